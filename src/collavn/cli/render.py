"""``collavn render``: one panorama (or goal view) of a scene, plus its depth picture."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import tyro
from PIL import Image

from collavn.errors import RenderError
from collavn.files import check_writable_file
from collavn.rendering.cameras import CameraSpec
from collavn.rendering.renderer import Renderer
from collavn.scenes.loading import load_scene
from collavn.scenes.scene import Scene
from collavn.scenes.spec import LoadOptions


@dataclass
class RenderCommand:
    """Render a panorama (or a goal view) at a pose; writes the image and its depth."""

    scene: Annotated[str, tyro.conf.Positional]
    """``procedural:SEED`` or a mesh file (.glb .gltf .obj .ply .dae)."""
    out: Path = Path("render.png")
    """Output PNG; the depth picture goes beside it as ``<stem>_depth.png``."""
    pose: str | None = None
    """Camera pose ``X,Y,YAW`` in metres and degrees (CCW from +x); default: the
    navigable cell nearest the centre of the largest navigable region, yaw 0."""
    goal: bool = False
    """Render the pinhole goal camera (90° FOV) instead of the 360° panorama."""
    width: int | None = None
    """Image width in pixels (default 512 for panoramas, 128 for goal views)."""
    height: int | None = None
    """Image height in pixels (default 128)."""
    backend: Literal["embree", "warp"] = "embree"
    """Ray caster: ``embree`` (CPU) or ``warp`` (NVIDIA Warp, CPU or CUDA)."""
    device: str = "cpu"
    """``cpu``, or ``cuda:N`` with the warp backend."""
    load: Annotated[LoadOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=LoadOptions)
    """How to load a mesh file (``--up-axis``, ``--scale``, ``--floor-height``)."""

    def run(self) -> int:
        """Load the scene, render one view, write both PNGs and print their paths."""
        check_writable_file(self.out, "--out")
        width = (128 if self.goal else 512) if self.width is None else self.width
        height = 128 if self.height is None else self.height
        spec = (CameraSpec.pinhole(width, height) if self.goal
                else CameraSpec.panorama(width, height))  # refuses bad sizes before loading
        scene = load_scene(self.load.spec(self.scene))
        pose = parse_pose(self.pose) if self.pose is not None else default_pose(scene)
        panorama, goal = (None, spec) if self.goal else (spec, None)
        with Renderer(scene, backend=self.backend, device=self.device, panorama=panorama,
                      goal=goal) as renderer:
            out = renderer.render(pose[None], camera="goal" if self.goal else "panorama")
        self.out.parent.mkdir(parents=True, exist_ok=True)
        depth_path = self.out.with_name(f"{self.out.stem}_depth.png")
        Image.fromarray(out.rgb[0].transpose(1, 2, 0)).save(self.out)
        Image.fromarray(depth_image(out.depth[0])).save(depth_path)
        x, y, yaw = pose
        print(f"{scene.name} at x={x:.2f} y={y:.2f} yaw={math.degrees(yaw):.1f}°: "
              f"{self.out} and {depth_path}")
        return 0


def parse_pose(text: str) -> np.ndarray:
    """``"X,Y,YAW"`` (yaw in degrees) → ``(3,)`` float64 ``x, y, yaw`` in radians."""
    try:
        x, y, yaw = (float(v) for v in text.split(","))
    except ValueError:
        raise RenderError(f"bad pose {text!r}: expected X,Y,YAW, e.g. 2.5,1.0,90") from None
    pose = np.array([x, y, math.radians(yaw)])
    if not np.isfinite(pose).all():
        raise RenderError(f"bad pose {text!r}: values must be finite")
    return pose


def default_pose(scene: Scene) -> np.ndarray:
    """The navigable cell nearest the centroid of the largest region, facing +x."""
    nav = scene.nav
    rows, cols = np.nonzero(nav.components == 1)
    centres = nav.cell_centers(rows, cols)
    k = int(np.argmin(np.linalg.norm(centres - centres.mean(axis=0), axis=1)))
    return np.array([centres[k, 0], centres[k, 1], 0.0])


def depth_image(depth: np.ndarray) -> np.ndarray:
    """``(H, W)`` metres → ``(H, W)`` uint8: near is bright, far dark, no hit black."""
    far = float(depth.max())
    if far <= 0.0:
        return np.zeros(depth.shape, np.uint8)
    img = 40.0 + 215.0 * (1.0 - depth / far)
    return np.where(depth > 0, img, 0.0).astype(np.uint8)
