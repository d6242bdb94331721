"""Score one policy on an episode dataset, and write the records and the paper's table.

``EvalConfig`` reuses :class:`~collavn.envs.config.EnvConfig` for what the agents sense
(image sizes, camera, odometry noise, renderer); the task and the number of agents come
from each dataset file (Ad-hoCoop: the file's N is the evaluation N), and a checkpoint
brings its own image sizes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, cast

from collavn.datasets.storage import Dataset
from collavn.envs.config import EnvConfig
from collavn.errors import CollavnError
from collavn.evaluation.runner import Trajectory, evaluate, write_records, write_trajectories
from collavn.metrics import AgentRecord, MetricsTable, metrics_table
from collavn.policies import make_policy
from collavn.scenes import load_scene
from collavn.tasks import TaskName


@dataclass(frozen=True)
class EvalConfig:
    """What to evaluate, on which episodes, and how."""

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
    seed: int = 0
    """Seeds the random policy, sampled checkpoint actions and odometry noise."""
    device: str = "cpu"
    """Torch device for checkpoint policies."""
    stochastic: bool = False
    """Checkpoints only: sample actions from the policy's Gaussian (seeded by ``--seed``)
    instead of taking its mean."""
    keep_trajectories: int = 6
    """Keep the paths of this many episodes per dataset file (for ``collavn viz``)."""
    progress: bool = True
    """Show a progress bar."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Sensors (task and agents come from the dataset; checkpoints bring their sizes)."""


def run_evaluation(cfg: EvalConfig, dataset: Dataset
                   ) -> tuple[list[AgentRecord], list[Trajectory]]:
    """Evaluate ``cfg.policy`` on every file of ``dataset``; records in file order."""
    from rich.progress import Progress

    records: list[AgentRecord] = []
    trajectories: list[Trajectory] = []
    with Progress(disable=not cfg.progress, transient=True) as bar:
        selected = {name: [e for e in content.episodes
                           if cfg.difficulty in (None, e.difficulty)]
                    for name, content in dataset.files.items()}
        task = bar.add_task(f"{cfg.policy}", total=sum(map(len, selected.values())))
        for name, content in dataset.files.items():
            episodes = selected[name]
            if not episodes:
                continue
            scene = load_scene(content.scene.source)
            content.check_scene(scene)
            policy, overrides = make_policy(cfg.policy, [scene], cfg.seed, cfg.device,
                                            cfg.stochastic)
            env = replace(cfg.env, task=cast(TaskName, content.task),
                          num_agents=content.num_agents, **overrides)
            result = evaluate(policy, scene, episodes, env, cfg.num_envs, cfg.seed,
                              cfg.keep_trajectories, on_episode=lambda k: bar.advance(task, k))
            records += result.records
            trajectories += result.trajectories
    return records, trajectories


def load_dataset(cfg: EvalConfig) -> Dataset:
    """The dataset ``cfg`` names, filtered by group and split; refuses an empty one."""
    dataset = Dataset.load(cfg.dataset, group=cfg.group, split=cfg.split)
    if len(dataset) == 0:
        raise CollavnError(f"no episodes in {cfg.dataset} for group={cfg.group} "
                           f"split={cfg.split}")
    return dataset


def write_results(out: Path, records: dict[str, list[AgentRecord]],
                  trajectories: Sequence[Trajectory]) -> MetricsTable:
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


def summary_json(table: MetricsTable) -> dict[str, Any]:
    """``{method: {"metrics": …, "counts": …}}`` of a table, for ``--json``."""
    return {row.method: {"metrics": row.groups, "counts": row.counts} for row in table.rows}
