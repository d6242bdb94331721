"""Small hand-built scenes whose geometry (and so whose answers) we know exactly."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

from collavn.scenes.builder import SceneBuilder, flat_texture
from collavn.scenes.scene import Scene

# The suite draws the same hypothesis examples on every run, so a red CI run can be
# repeated; HYPOTHESIS_PROFILE=explore searches new examples (run it now and then).
settings.register_profile("ci", derandomize=True)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

SHARED_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"


def _shared_scene(name: str) -> Path:
    path = SHARED_SCENES / name
    if not path.is_file():
        pytest.skip(f"real test scene {path} not present (it lives beside the repo in CI)")
    return path


@pytest.fixture(scope="session")
def shared_scene():
    """``shared_scene(name)``: path of a real scene in ../shared/scenes, or skip saying why."""
    return _shared_scene


def _builder() -> tuple[SceneBuilder, int, int]:
    b = SceneBuilder(texture_size=8)
    floor = b.material("floor", flat_texture((150, 120, 90), 8))
    wall = b.material("wall", flat_texture((220, 220, 210), 8))
    return b, floor, wall


@pytest.fixture(scope="session")
def l_corridor() -> Scene:
    """10×10 m floor; a solid block fills x,y ∈ [2, 10]: an L-shaped corridor 2 m wide."""
    b, floor, wall = _builder()
    b.add_box((0, 0, -0.1), (10, 10, 0), floor)
    b.add_box((2, 2, 0), (10, 10, 2.5), wall)
    return b.build("l-corridor")


@pytest.fixture(scope="session")
def door_scene() -> Scene:
    """10×6 m room split by a 0.1 m wall at x ∈ [5, 5.1] with a door at y ∈ [3, 4]."""
    b, floor, wall = _builder()
    b.add_box((0, 0, -0.1), (10, 6, 0), floor)
    b.add_box((5, 0, 0), (5.1, 3, 2.5), wall)
    b.add_box((5, 4, 0), (5.1, 6, 2.5), wall)
    return b.build("door")


@pytest.fixture(scope="session")
def open_room() -> Scene:
    """An empty 8×8 m room with 0.1 m walls around it."""
    b, floor, wall = _builder()
    b.add_box((0, 0, -0.1), (8, 8, 0), floor)
    for lo, hi in (((0, 0, 0), (8, 0.1, 2.5)), ((0, 7.9, 0), (8, 8, 2.5)),
                   ((0, 0, 0), (0.1, 8, 2.5)), ((7.9, 0, 0), (8, 8, 2.5))):
        b.add_box(lo, hi, wall)
    return b.build("open-room")
