"""``collavn evaluate`` and ``collavn viz``: scores and pictures from episode datasets."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from collavn.datasets.storage import Dataset
from collavn.envs.config import EnvConfig
from collavn.errors import CollavnError
from collavn.evaluation.policies import OraclePolicy, Policy, RandomPolicy
from collavn.evaluation.runner import (
    Trajectory,
    evaluate,
    read_trajectories,
    write_records,
    write_trajectories,
)
from collavn.metrics import AgentRecord, metrics_table
from collavn.scenes import load_scene
from collavn.scenes.scene import Scene


def make_policy(name: str, scenes: Sequence[Scene], seed: int = 0,
                device: str = "cpu", stochastic: bool = False
                ) -> tuple[Policy, dict[str, Any]]:
    """``random``, ``oracle`` or a checkpoint path → (policy, env overrides it needs)."""
    if name == "random":
        return RandomPolicy(seed), {}
    if name == "oracle":
        return OraclePolicy(scenes), {"privileged": True}
    path = Path(name)
    if not path.exists():
        raise CollavnError(f"unknown policy {name!r}: use random, oracle or a checkpoint file")
    from collavn.training.checkpoint import load_policy

    return load_policy(path, device=device, stochastic=stochastic, seed=seed)


def run_evaluation(policy_name: str, dataset: Dataset, base: EnvConfig, num_envs: int = 4,
                   seed: int = 0, keep_trajectories: int = 6, progress: bool = True,
                   device: str = "cpu", difficulty: str | None = None,
                   stochastic: bool = False) -> tuple[list[AgentRecord], list[Trajectory]]:
    """Evaluate one policy on every file of ``dataset``; records in file order.

    ``difficulty`` keeps only the episodes of that bin (``easy``, ``medium``, ``hard``).
    """
    from rich.progress import Progress

    records: list[AgentRecord] = []
    trajectories: list[Trajectory] = []
    with Progress(disable=not progress, transient=True) as bar:
        selected = {name: [e for e in content.episodes
                           if difficulty in (None, e.difficulty)]
                    for name, content in dataset.files.items()}
        task = bar.add_task(f"{policy_name}", total=sum(map(len, selected.values())))
        for name, content in dataset.files.items():
            episodes = selected[name]
            if not episodes:
                continue
            scene = load_scene(content.scene.source)
            content.check_scene(scene)
            policy, overrides = make_policy(policy_name, [scene], seed, device, stochastic)
            config = replace(base, task=content.task, num_agents=content.num_agents,
                             **overrides)
            result = evaluate(policy, scene, episodes, config, num_envs, seed,
                              keep_trajectories, on_episode=lambda k: bar.advance(task, k))
            records += result.records
            trajectories += result.trajectories
    return records, trajectories


@dataclass
class Evaluate:
    """Score a policy on an episode dataset: per-episode records and the paper's table."""

    policy: str = "random"
    """``random``, ``oracle`` (privileged shortest-path follower), or a checkpoint file."""
    dataset: Path = Path("data/episodes")
    """Dataset directory (made by ``collavn dataset generate``)."""
    out: Path = Path("runs/eval")
    """Where to write ``records.jsonl``, ``trajectories.jsonl`` and ``metrics.{md,tex,csv}``."""
    split: str | None = None
    """Only this split (default: all in the dataset)."""
    group: str | None = None
    """Only this task setting, e.g. ``commongoal_n2`` or ``adhocoop_n2to3``."""
    difficulty: Literal["easy", "medium", "hard"] | None = None
    """Only the episodes of this difficulty bin."""
    num_envs: int = 4
    """Environments stepped together."""
    panorama_width: int = 512
    """Panorama width (checkpoints bring their own sizes)."""
    panorama_height: int = 128
    """Panorama height."""
    goal_size: int = 128
    """Goal image side."""
    seed: int = 0
    """Seeds the random policy and odometry noise."""
    device: str = "cpu"
    """Torch device for checkpoint policies."""
    stochastic: bool = False
    """Checkpoints only: sample actions from the policy's Gaussian (seeded by ``--seed``)
    instead of taking its mean."""
    json: bool = False
    """Print the metrics as JSON instead of a table."""

    def run(self) -> int:
        """Evaluate, write files, print the table."""
        dataset = Dataset.load(self.dataset, group=self.group, split=self.split)
        if len(dataset) == 0:
            raise CollavnError(f"no episodes in {self.dataset} for group={self.group} "
                               f"split={self.split}")
        base = EnvConfig(panorama_width=self.panorama_width,
                         panorama_height=self.panorama_height, goal_size=self.goal_size)
        records, trajectories = run_evaluation(self.policy, dataset, base, self.num_envs,
                                               self.seed, device=self.device,
                                               difficulty=self.difficulty,
                                               stochastic=self.stochastic)
        if not records:
            raise CollavnError(f"no {self.difficulty} episodes in {self.dataset}")
        table = write_results(self.out, {self.policy: records}, trajectories)
        if self.json:
            print(json.dumps({row.method: {"metrics": row.groups, "counts": row.counts}
                              for row in table.rows}, indent=2))
        else:
            print(table.to_markdown())
        return 0


def write_results(out: Path, records: dict[str, list[AgentRecord]],
                  trajectories: Sequence[Trajectory]) -> Any:
    """Write records (one file per policy), trajectories and the metrics table."""
    out.mkdir(parents=True, exist_ok=True)
    for name, recs in records.items():
        stem = "records" if len(records) == 1 else f"records_{Path(name).stem}"
        write_records(out / f"{stem}.jsonl", recs)
    write_trajectories(out / "trajectories.jsonl", trajectories)
    table = metrics_table(records)
    (out / "metrics.md").write_text(table.to_markdown() + "\n")
    (out / "metrics.tex").write_text(table.to_latex() + "\n")
    (out / "metrics.csv").write_text(table.to_csv())
    return table


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
        path = self.records / "trajectories.jsonl" if self.records.is_dir() else self.records
        if not path.is_file():
            raise CollavnError(f"no trajectories at {path}: run `collavn evaluate` first")
        trajectories = read_trajectories(path)
        if not trajectories:
            raise CollavnError(f"{path} holds no trajectories")
        for written in draw_all(trajectories, self.out, self.gifs, self.panorama_width):
            print(written)
        return 0


def draw_all(trajectories: Sequence[Trajectory], out: Path, gifs: int = 1,
             panorama_width: int = 256) -> list[Path]:
    """Maps (one PNG per scene) and ``gifs`` animations; returns the written paths."""
    from collavn.viz.animate import animate_episode
    from collavn.viz.trajectories import save_trajectory_maps

    written = []
    by_scene: dict[str, list[Trajectory]] = {}
    for t in trajectories:
        by_scene.setdefault(t.scene, []).append(t)
    scenes = {source: load_scene(source) for source in by_scene}
    for k, (source, trajs) in enumerate(by_scene.items()):
        name = "trajectories.png" if len(by_scene) == 1 else f"trajectories_{k}.png"
        written.append(save_trajectory_maps(scenes[source], trajs, out / name))
    for t in trajectories[:gifs]:
        safe = t.episode_id.replace("/", "_").replace(":", "-")
        written.append(animate_episode(scenes[t.scene], t, out / f"episode_{safe}.gif",
                                       panorama_width))
    return written
