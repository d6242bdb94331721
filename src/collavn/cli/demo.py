"""``collavn demo``: the whole benchmark loop on one procedural scene, in about a minute.

Generates a few CommonGoal episodes per difficulty, evaluates the shortest-path
oracle and the random policy on them, prints the paper-style metrics table, and
writes pictures: the scene map, trajectory maps per policy and an animated episode.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import tyro

from collavn.datasets.build import generate_dataset
from collavn.datasets.generator import Preset
from collavn.datasets.storage import Dataset
from collavn.envs.config import EnvConfig
from collavn.evaluation.benchmark import EvalConfig, run_evaluation, write_results
from collavn.metrics import metrics_table
from collavn.scenes import LoadOptions, load_scene
from collavn.viz.animate import draw_all
from collavn.viz.topdown import save_scene_map


@dataclass
class Demo:
    """Generate episodes, evaluate oracle and random, print the table, draw pictures."""

    scene: str = "procedural:0"
    """Scene spec: ``procedural:SEED`` or a mesh file."""
    load: Annotated[LoadOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=LoadOptions)
    """How to load a mesh file (``--up-axis``, ``--scale``, ``--floor-height``)."""
    out: Path = Path("demo_out")
    """Output directory."""
    agents: int = 2
    """Agents per episode (CommonGoal)."""
    episodes: int = 3
    """Episodes per difficulty (easy, medium, hard)."""
    panorama_width: int = 256
    """Panorama width (height = width / 4); the paper uses 512."""
    seed: int = 0
    """Seeds episode generation and the random policy."""

    def run(self) -> int:
        """Run the demo and print where everything went."""
        start = time.perf_counter()
        scene = load_scene(self.load.spec(self.scene))
        save_scene_map(scene, self.out / "scene_map.png")
        preset = Preset("demo", train=self.episodes, val=self.episodes, test=self.episodes)
        generate_dataset(self.out / "episodes", [scene], "commongoal", self.agents, "test",
                         preset=preset, seed=self.seed, progress=True)
        dataset = Dataset.load(self.out / "episodes")
        base = EnvConfig(panorama_width=self.panorama_width,
                         panorama_height=self.panorama_width // 4,
                         goal_size=self.panorama_width // 4)
        records = {}
        for policy in ("oracle", "random"):
            cfg = EvalConfig(policy=policy, num_envs=4, seed=self.seed, env=base,
                             keep_trajectories=3 * self.episodes)
            result = run_evaluation(cfg, dataset)
            write_results(self.out / policy, {policy: result})
            records[policy] = result.records
            pictures = draw_all(result.trajectories, self.out / policy,
                                gifs=1 if policy == "oracle" else 0,
                                panorama_width=self.panorama_width)
            print(f"{policy}: " + ", ".join(str(p) for p in pictures))
        table = metrics_table(records)
        (self.out / "metrics.md").write_text(table.to_markdown() + "\n")
        print()
        print(f"CommonGoal, N={self.agents}, {len(dataset)} episodes on {scene.name}:")
        print(table.to_markdown())
        print(f"\nwrote {self.out}/ in {time.perf_counter() - start:.1f} s")
        return 0
