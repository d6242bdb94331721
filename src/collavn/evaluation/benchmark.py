"""Score one policy on an episode dataset, and write the records and the paper's table.

``EvalConfig`` reuses :class:`~collavn.envs.config.EnvConfig` for what the agents sense
(image sizes, camera, odometry noise, renderer); the task and the number of agents come
from each dataset file (Ad-hoCoop: the file's N is the evaluation N), and a checkpoint
brings its own image sizes.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, cast

from collavn.configs import check_count
from collavn.datasets.episode import Difficulty
from collavn.datasets.storage import Dataset
from collavn.envs.config import EnvConfig
from collavn.errors import CollavnError
from collavn.evaluation.runner import (
    EvaluationResult,
    evaluate,
    write_records,
    write_trajectories,
)
from collavn.metrics import (
    AgentRecord,
    MetricsTable,
    metrics_table,
    search_groups,
    search_table,
)
from collavn.policies import make_policy
from collavn.scenes import load_scene
from collavn.tasks import TaskName
from collavn.threads import apply_threads


@dataclass(frozen=True)
class EvalConfig:
    """What to evaluate, on which episodes, and how."""

    policy: str = "random"
    """``random``, ``explorer`` (goal-blind: straight on, turn when blocked), ``oracle``
    (privileged shortest-path follower), ``seeker`` (explorer until the goal is in sight,
    then oracle; an ``il`` expert), or a checkpoint file."""
    dataset: Path = Path("data/episodes")
    """Dataset directory (made by ``collavn dataset generate``)."""
    out: Path = Path("runs/eval")
    """Where to write ``records.jsonl``, ``trajectories.jsonl`` and ``metrics.{md,tex,csv}``."""
    split: str | None = None
    """Only this split (default: all in the dataset)."""
    group: str | None = None
    """Only this task setting, e.g. ``commongoal_n2`` or ``adhocoop_n2to3``."""
    difficulty: Difficulty | None = None
    """Only the episodes of this difficulty bin."""
    num_envs: int = 4
    """Environments stepped together (a speed setting: results do not depend on it)."""
    seed: int = 0
    """Seeds the random policy, sampled checkpoint actions and odometry noise, per
    episode (with the episode's id)."""
    device: str = "cpu"
    """Torch device for checkpoint policies."""
    torch_threads: int = 0
    """torch / Numba threads; 0 = automatic: one each, as in ``train`` (two processes
    can share two cores)."""
    stochastic: bool = False
    """Checkpoints only: sample actions from the policy's Gaussian (seeded by ``--seed``)
    instead of taking its mean."""
    mute: bool = False
    """Checkpoints with communication: cut every link between teammates (each agent
    matches only its own memory; its gate and η unchanged): an ablation of what the
    messages add. Compare with the same checkpoint without ``--mute``."""
    keep_trajectories: int = 6
    """Keep the paths of this many episodes per dataset file (for ``collavn viz``)."""
    progress: bool = True
    """Show a progress bar."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Sensors (task and agents come from the dataset; checkpoints bring their sizes)."""

    def __post_init__(self) -> None:
        check_count("--num-envs", self.num_envs)
        check_count("--seed", self.seed, 0)
        check_count("--keep-trajectories", self.keep_trajectories, 0)
        check_count("--torch-threads", self.torch_threads, 0)


def run_evaluation(cfg: EvalConfig, dataset: Dataset) -> EvaluationResult:
    """Evaluate ``cfg.policy`` on every file of ``dataset``; records in file order."""
    from rich.progress import Progress

    apply_threads(cfg.torch_threads)
    total = EvaluationResult()
    with Progress(disable=not cfg.progress, transient=True) as bar:
        selected = {name: [e for e in content.episodes
                           if cfg.difficulty in (None, e.difficulty)]
                    for name, content in dataset.files.items()}
        task = bar.add_task(f"{cfg.policy}", total=sum(map(len, selected.values())))
        for name, content in dataset.files.items():
            episodes = selected[name]
            if not episodes:
                continue
            scene = load_scene(content.scene.spec)
            content.check_scene(scene)
            policy, overrides = make_policy(cfg.policy, [scene], cfg.seed, cfg.device,
                                            cfg.stochastic, mute=cfg.mute)
            env = replace(cfg.env, task=cast(TaskName, content.task),
                          num_agents=content.num_agents, **overrides)
            total.add(evaluate(policy, scene, episodes, env, cfg.num_envs, cfg.seed,
                               cfg.keep_trajectories,
                               on_episode=lambda k: bar.advance(task, k)))
    return total


def load_dataset(cfg: EvalConfig) -> Dataset:
    """The dataset ``cfg`` names, filtered by group and split; refuses an empty one."""
    dataset = Dataset.load(cfg.dataset, group=cfg.group, split=cfg.split)
    if len(dataset) == 0:
        raise CollavnError(f"no episodes in {cfg.dataset} for group={cfg.group} "
                           f"split={cfg.split}")
    return dataset


@dataclass(frozen=True)
class Report:
    """The paper's table of one or more methods, with their communication.

    Attributes:
        table: SR / DTS / SPL / SSR by difficulty, one row per method.
        communication: Per method: ``received_rate``, ``when_rate``,
            ``bytes_per_agent_step`` (see :class:`~collavn.policies.base.CommStats`).
    """

    table: MetricsTable
    communication: dict[str, dict[str, float]]

    search: dict[str, list[AgentRecord]] = field(default_factory=dict)
    """Per method, the records :func:`~collavn.metrics.search_table` splits into search
    and homing (empty: not shown)."""

    def to_markdown(self) -> str:
        """The metrics table, one line of communication per method, search and homing."""
        text = self.table.to_markdown() + "\n\n" + communication_table(self.communication)
        if any(r.sighted_step is not None for recs in self.search.values() for r in recs):
            text += "\n\n" + search_table(self.search)
        return text

    def to_json(self) -> dict[str, Any]:
        """``{method: {"metrics", "counts", "communication", "search"}}``, for ``--json``.

        ``search``: :func:`~collavn.metrics.search_groups` (per difficulty and overall).
        """
        return {row.method: {"metrics": row.groups, "counts": row.counts,
                             "communication": self.communication.get(row.method, {}),
                             "search": search_groups(self.search.get(row.method, []))}
                for row in self.table.rows}


def communication_table(rates: dict[str, dict[str, float]]) -> str:
    """Markdown: a row per method of :meth:`CommStats.rates` (missing rates count as 0)."""
    lines = ["| method | comm. received | comm. when | bytes / agent-step |",
             "|---|---:|---:|---:|"]
    for name, c in rates.items():
        lines.append(f"| {name} | {c.get('received_rate', 0.0):.3f} | "
                     f"{c.get('when_rate', 0.0):.3f} | "
                     f"{c.get('bytes_per_agent_step', 0.0):.1f} |")
    return "\n".join(lines)


def write_results(out: Path, results: dict[str, EvaluationResult]) -> Report:
    """Write records (one file per policy), trajectories, the table and communication."""
    out.mkdir(parents=True, exist_ok=True)
    for name, result in results.items():
        stem = "records" if len(results) == 1 else f"records_{Path(name).stem}"
        write_records(out / f"{stem}.jsonl", result.records)
    write_trajectories(out / "trajectories.jsonl",
                       [t for r in results.values() for t in r.trajectories])
    report = Report(metrics_table({k: r.records for k, r in results.items()}),
                    {k: r.communication.rates() for k, r in results.items()},
                    {k: r.records for k, r in results.items()})
    (out / "metrics.md").write_text(report.to_markdown() + "\n")
    (out / "metrics.tex").write_text(report.table.to_latex() + "\n")
    (out / "metrics.csv").write_text(report.table.to_csv())
    (out / "metrics.json").write_text(json.dumps(report.to_json(), indent=2) + "\n")
    return report
