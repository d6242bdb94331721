"""``collavn viz``: trajectory maps and an animated episode from an evaluation."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from collavn.configs import check_count
from collavn.errors import CollavnError
from collavn.evaluation.runner import read_trajectories
from collavn.viz.animate import draw_all


@dataclass
class Viz:
    """Draw trajectory maps and an animated GIF from an evaluation's output directory."""

    records: Annotated[Path, tyro.conf.Positional]
    """Evaluation output directory (holding ``trajectories.jsonl``) or that file itself."""
    out: Path = Path("runs/viz")
    """Where to write ``trajectories.png`` and ``episode_*.gif``."""
    gifs: int = 1
    """How many episodes to animate."""
    panorama_width: int = 256
    """Panorama width in the GIF (re-rendered from the stored poses)."""

    def run(self) -> int:
        """Read trajectories, draw."""
        check_count("--gifs", self.gifs, 0)
        check_count("--panorama-width", self.panorama_width)
        path = self.records / "trajectories.jsonl" if self.records.is_dir() else self.records
        if not path.is_file():
            raise CollavnError(f"no trajectories at {path}: run `collavn evaluate` first")
        trajectories = read_trajectories(path)
        if not trajectories:
            raise CollavnError(f"{path} holds no trajectories")
        for written in draw_all(trajectories, self.out, self.gifs, self.panorama_width):
            print(written)
        return 0
