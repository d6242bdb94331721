"""`collavn dataset generate` and `collavn dataset info`."""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
import tyro
from rich.console import Console
from rich.table import Table

from collavn.datasets.build import generate_dataset
from collavn.datasets.episode import DIFFICULTY_BINS
from collavn.datasets.generator import PRESETS, Preset
from collavn.datasets.storage import Dataset
from collavn.errors import DatasetError
from collavn.scenes import LoadOptions, load_scene
from collavn.scenes.splits import Split
from collavn.tasks import TaskName

#: Histogram bin edges of geodesic start-to-goal distances, metres.
HISTOGRAM_EDGES = np.arange(1.5, 10.01, 0.5)


@dataclass
class DatasetGenerate:
    """Generate episodes of one task setting and split into a dataset directory."""

    task: TaskName = "commongoal"
    """Task setting: one shared goal, one goal per agent, or shared goal with a
    different number of agents at evaluation."""
    agents: int = 2
    """Number of agents N (Ad-hoCoop: the training N)."""
    eval_agents: int | None = None
    """Ad-hoCoop only: N' of val/test episodes (default 2→3, 3→2)."""
    split: Split = "val"
    """Split to generate."""
    preset: Literal["paper", "small"] = "small"
    """Episode counts: paper (5,000 train per scene; 500 val / 1,000 test per scene and
    difficulty) or small (20 train; 10 val/test per difficulty)."""
    episodes: int | None = None
    """Override the preset's count for this split: episodes per scene *per difficulty*
    for val/test, per scene for train."""
    out: Path = Path("data/episodes")
    """Dataset directory; files go to OUT/<task>_n<N>/<split>/<scene>.json.gz."""
    seed: int = 0
    """Master seed: the same seed gives byte-identical files."""
    scenes: tuple[str, ...] = ()
    """Scene specs (procedural:SEED, a mesh path or a saved .npz scene); default: the
    procedural scenes of the split."""
    quiet: bool = False
    """Do not show a progress bar."""
    load: Annotated[LoadOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=LoadOptions)
    """How to load mesh files (``--up-axis``, ``--scale``, ``--floor-height``; the same
    for every mesh in ``--scenes``); recorded in the episode files."""

    def run(self) -> int:
        """Load the scenes, generate, write files and index; print what was written."""
        specs = list(self.scenes) or _default_specs(self.split)
        scenes = [load_scene(self.load.spec(s)) for s in specs]
        preset: str | Preset = self.preset
        if self.episodes is not None:
            if self.episodes < 1:
                raise DatasetError(f"--episodes must be ≥ 1, got {self.episodes}")
            name = f"{self.preset}-{self.split}{self.episodes}"
            preset = replace(PRESETS[self.preset], name=name, **{self.split: self.episodes})
        paths = generate_dataset(self.out, scenes, self.task, self.agents, self.split,
                                 preset, self.seed, self.eval_agents,
                                 progress=not self.quiet)
        for p in paths:
            print(p)
        return 0


@dataclass
class DatasetInfo:
    """Summarise a dataset directory: episodes per scene and difficulty, distances."""

    path: tyro.conf.Positional[Path]
    """Dataset directory (holding index.json)."""
    json: bool = False
    """Print a JSON object instead of tables."""

    def run(self) -> int:
        """Load (and verify) every file, then print the summary."""
        info = dataset_summary(Dataset.load(self.path))
        if self.json:
            print(json.dumps(info, indent=1, sort_keys=True))
            return 0
        console = Console()
        table = Table("setting", "split", "scene", "N", *DIFFICULTY_BINS, "total",
                      title=f"episodes in {self.path}")
        for f in info["files"]:
            table.add_row(f["path"].split("/")[0], f["split"], f["scene"],
                          str(f["num_agents"]),
                          *(str(f["difficulties"].get(d, 0)) for d in DIFFICULTY_BINS),
                          str(f["episodes"]))
        console.print(table)
        console.print(f"fingerprint {info['fingerprint']} (equal on any two machines iff "
                      "the episodes are)")
        edges = info["histogram_edges"]
        for group, hist in info["histograms"].items():
            console.print(f"\ngeodesic start-to-goal distance, all agents: {group}")
            top = max(max(hist), 1)
            for lo, hi, k in zip(edges[:-1], edges[1:], hist, strict=True):
                console.print(f"  [{lo:4.1f}, {hi:4.1f}) m {k:7d} " + "█" * round(40 * k / top))
        return 0


def dataset_summary(dataset: Dataset) -> dict[str, Any]:
    """Counts per file and difficulty; distance histograms per ``group/split``; a fingerprint.

    The fingerprint (16 hex digits) hashes every file's path and content hash, which covers
    its episodes and its scene's geometry and navigation: two datasets made on different
    machines by the same command hold the same episodes only if their fingerprints match.
    """
    files: list[dict[str, Any]] = []
    hists: dict[str, np.ndarray] = {}
    for path, content in dataset.files.items():
        group = f"{Path(path).parts[0]}/{content.split}"
        difficulties: dict[str, int] = {}
        for e in content.episodes:
            difficulties[e.difficulty] = difficulties.get(e.difficulty, 0) + 1
        dists = [d for e in content.episodes for d in e.start_distances.tolist()]
        counts = np.histogram(np.asarray(dists, dtype=np.float64), bins=HISTOGRAM_EDGES)[0]
        hists[group] = hists.get(group, np.zeros_like(counts)) + counts
        files.append({"path": path, "task": content.task, "num_agents": content.num_agents,
                      "split": content.split, "scene": content.scene.name,
                      "episodes": len(content.episodes), "difficulties": difficulties,
                      "content_hash": content.content_hash})
    listing = "\n".join(f"{f['path']} {f['content_hash']}" for f in sorted(
        files, key=lambda f: f["path"]))
    return {"root": str(dataset.root), "episodes": len(dataset), "files": files,
            "fingerprint": hashlib.sha256(listing.encode()).hexdigest()[:16],
            "histogram_edges": HISTOGRAM_EDGES.round(2).tolist(),
            "histograms": {g: h.tolist() for g, h in hists.items()}}


def _default_specs(split: str) -> list[str]:
    from collavn.scenes.splits import scene_specs

    return list(scene_specs(split))
