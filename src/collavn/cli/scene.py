"""``collavn scene info``: describe a scene and draw its map."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import tyro

from collavn.files import check_writable_file
from collavn.scenes.loading import load_scene
from collavn.scenes.spec import LoadOptions
from collavn.scenes.summary import scene_summary


@dataclass
class SceneInfo:
    """Describe a scene: triangles, bounds, navigable area, components, geodesic span."""

    scene: Annotated[str, tyro.conf.Positional]
    """``procedural:SEED`` or a mesh file (.glb .gltf .obj .ply .dae)."""
    json: bool = False
    """Print JSON instead of a table."""
    map: Path | None = None
    """Also write a top-down map PNG (navigable area, obstacles, components, scale)."""
    load: Annotated[LoadOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=LoadOptions)
    """How to load a mesh file (``--up-axis``, ``--scale``, ``--floor-height``)."""

    def run(self) -> int:
        """Load, summarise, print; optionally draw."""
        if self.map is not None:
            check_writable_file(self.map, "--map")
        scene = load_scene(self.load.spec(self.scene))
        info = scene_summary(scene)
        if self.map is not None:
            from collavn.viz.topdown import save_scene_map

            info["map"] = str(save_scene_map(scene, self.map))
        if self.json:
            print(json.dumps(info, indent=2))
        else:
            from rich.console import Console
            from rich.table import Table

            table = Table(title=f"scene {info['name']}", show_header=False)
            for key, value in info.items():
                table.add_row(key, str(value))
            Console().print(table)
        return 0
