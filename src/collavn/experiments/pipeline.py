"""The paper's table end to end: datasets → training → evaluation → comparisons → report.

:func:`run_experiment` runs named *stages* in order. Each stage records, when it has
finished, what it produced and the command line that does the same by hand in
``OUT/stages/<name>.json``; running the experiment again with the same arguments skips
every finished stage (a training stage interrupted half-way continues from its
checkpoint with ``--resume``). Different arguments into the same ``OUT`` are refused.

The time budget is shared before anything runs and printed: a fixed share for the
evaluations, the rest split evenly over the four learning methods (each training
stage stops at its share, with a checkpoint). Datasets and evaluation sizes are
set by :class:`ExperimentConfig`, not by the budget.
"""

from __future__ import annotations

import functools
import hashlib
import json
import shlex
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from collavn.configs import check_count, check_number
from collavn.datasets.build import generate_dataset
from collavn.datasets.generator import Preset
from collavn.errors import CollavnError, ConfigError
from collavn.evaluation.benchmark import EvalConfig, load_dataset, run_evaluation, write_results
from collavn.scenes import load_scene
from collavn.scenes.splits import scene_specs
from collavn.training.config import PresetName
from collavn.training.presets import PRESETS, parse_train_args

#: The learning methods of the table, in the paper's order.
LEARNED = ("il", "no-com", "no-mem", "ours")
#: Baselines evaluated beside them.
BASELINES = ("random", "explorer", "oracle")


@dataclass(frozen=True)
class ExperimentConfig:
    """The paper's CommonGoal table (and Ad-hoCoop) for a compute budget."""

    out: Path = Path("runs/experiment")
    """Experiment directory: datasets, runs, evaluations, ``report.md``."""
    preset: PresetName = "cpu"
    """Training preset of every method (``cpu`` on a laptop, ``paper`` on GPUs)."""
    budget_minutes: float = 120.0
    """Wall-clock budget of the training and evaluation stages, shared up front."""
    eval_share: float = 0.25
    """Share of the budget kept for evaluation (the rest trains the four methods)."""
    agents: int = 2
    """N of the CommonGoal table."""
    adhoc_agents: int = 3
    """N' at which the N-agent ``ours`` is evaluated (Ad-hoCoop)."""
    episodes: int = 10
    """Test episodes per scene and difficulty (5 test scenes × 3 difficulties × this)."""
    seed: int = 0
    """Seeds datasets, training and evaluation."""
    num_envs: int = 8
    """Envs stepped together in evaluation."""
    samples: int = 5000
    """Bootstrap resamples of the comparisons."""
    device: str = "cpu"
    """Torch device of training and evaluation."""
    torch_threads: int = 0
    """Torch threads of the training runs (0 = automatic: one per run, see ``train``)."""
    progress: bool = True
    """Show progress bars."""
    test_scenes: tuple[str, ...] = ()
    """Scenes of the test datasets (default: the 5 procedural test scenes)."""
    train_args: str = ""
    """Extra ``collavn train`` flags for every method, e.g. ``"--scenes procedural:0
    --num-envs 4"``."""

    def __post_init__(self) -> None:
        check_number("--budget-minutes", self.budget_minutes)
        check_number("--eval-share", self.eval_share)
        if self.eval_share >= 1:
            raise ConfigError(f"--eval-share must be < 1, got {self.eval_share}")
        for name in ("agents", "adhoc_agents", "episodes", "num_envs", "samples"):
            check_count("--" + name.replace("_", "-"), getattr(self, name))
        check_count("--torch-threads", self.torch_threads, minimum=0)

    @property
    def train_minutes(self) -> float:
        """Training budget of each learning method."""
        return self.budget_minutes * (1 - self.eval_share) / len(LEARNED)

    def identity(self) -> dict[str, Any]:
        """The arguments that must match to resume an experiment directory."""
        d = json.loads(json.dumps(asdict(self), default=str))
        for name in ("out", "progress", "device", "torch_threads"):
            d.pop(name)
        return d


@dataclass
class Stage:
    """One step of the pipeline: a name, its command line, and what runs it."""

    name: str
    command: list[str]
    run: Callable[[], dict[str, Any]]
    result: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0


def check_out(cfg: ExperimentConfig) -> None:
    """Create ``OUT`` or check that it holds an experiment with the same arguments."""
    marker = cfg.out / "experiment.json"
    if marker.is_file():
        saved = json.loads(marker.read_text())
        if saved != cfg.identity():
            diff = sorted(k for k in set(saved) | set(cfg.identity())
                          if saved.get(k) != cfg.identity().get(k))
            raise CollavnError(f"{cfg.out} holds an experiment with other arguments "
                               f"({', '.join(diff)}); use another --out")
    elif cfg.out.exists() and any(cfg.out.iterdir()):
        raise CollavnError(f"{cfg.out} is not empty and holds no experiment; use another "
                           f"--out")
    cfg.out.mkdir(parents=True, exist_ok=True)
    marker.write_text(json.dumps(cfg.identity(), indent=2) + "\n")


def stages(cfg: ExperimentConfig) -> list[Stage]:
    """Every stage of the experiment, in order."""
    out, preset = cfg.out, cfg.preset
    env = PRESETS[preset][1].env
    sizes = ["--panorama-width", str(env.panorama_width), "--panorama-height",
             str(env.panorama_height), "--goal-size", str(env.goal_size)]
    test, adhoc = out / "data" / "test", out / "data" / "adhoc"
    scenes = ["--scenes", *cfg.test_scenes] if cfg.test_scenes else []
    found = [
        Stage("dataset-test", ["collavn", "dataset", "generate", "--task", "commongoal",
                               "--agents", str(cfg.agents), "--split", "test", "--episodes",
                               str(cfg.episodes), "--seed", str(cfg.seed), "--out",
                               str(test), *scenes],
              lambda: _dataset(cfg, test, "commongoal", None)),
        Stage("dataset-adhoc", ["collavn", "dataset", "generate", "--task", "adhocoop",
                                "--agents", str(cfg.agents), "--eval-agents",
                                str(cfg.adhoc_agents), "--split", "test", "--episodes",
                                str(cfg.episodes), "--seed", str(cfg.seed), "--out",
                                str(adhoc), *scenes],
              lambda: _dataset(cfg, adhoc, "adhocoop", cfg.adhoc_agents)),
    ]
    for method in LEARNED:
        args = ["--preset", preset, "--method", method, "--agents", str(cfg.agents),
                "--seed", str(cfg.seed), "--time-budget-minutes", f"{cfg.train_minutes:g}",
                "--out", str(out / "runs" / method), "--device", cfg.device,
                "--torch-threads", str(cfg.torch_threads),
                *([] if cfg.progress else ["--no-progress"]), *shlex.split(cfg.train_args)]
        found.append(Stage(f"train-{method}", ["collavn", "train", *args],
                           functools.partial(_train, args)))
    for name in (*LEARNED, *BASELINES):
        policy = str(out / "runs" / name / "checkpoint.pt") if name in LEARNED else name
        found.append(_evaluation(cfg, f"eval-{name}", policy, test, out / "eval" / name,
                                 [] if name in LEARNED else sizes))
    found.append(_evaluation(cfg, "eval-adhoc-ours",
                             str(out / "runs" / "ours" / "checkpoint.pt"), adhoc,
                             out / "eval" / f"ours-n{cfg.adhoc_agents}", []))
    return found


def run_experiment(cfg: ExperimentConfig, report: Callable[[ExperimentConfig, list[Stage]],
                                                            Path],
                   log: Callable[[str], None] = print) -> Path:
    """Run (or resume) every stage, then write the report; returns its path."""
    check_out(cfg)
    log(f"budget {cfg.budget_minutes:g} min: {len(LEARNED)} × {cfg.train_minutes:.1f} min "
        f"training ({', '.join(LEARNED)}), {cfg.budget_minutes * cfg.eval_share:.1f} min "
        f"for evaluating {len(LEARNED) + len(BASELINES) + 1} policies")
    done_dir = cfg.out / "stages"
    done_dir.mkdir(exist_ok=True)
    todo = stages(cfg)
    for stage in todo:
        marker = done_dir / f"{stage.name}.json"
        if marker.is_file():
            saved = json.loads(marker.read_text())
            stage.result, stage.seconds = saved["result"], saved["seconds"]
            log(f"[{stage.name}] done before, skipped")
            continue
        log(f"[{stage.name}] {shlex.join(stage.command)}")
        start = time.perf_counter()
        stage.result = stage.run()
        stage.seconds = time.perf_counter() - start
        marker.write_text(json.dumps({"command": stage.command, "result": stage.result,
                                      "seconds": stage.seconds}, indent=2) + "\n")
    return report(cfg, todo)


# ------------------------------------------------------------------ stage bodies
def _dataset(cfg: ExperimentConfig, out: Path, task: str, eval_agents: int | None
             ) -> dict[str, Any]:
    scenes = [load_scene(s) for s in cfg.test_scenes or scene_specs("test")]
    counts = Preset("experiment", train=1, val=cfg.episodes, test=cfg.episodes)
    paths = generate_dataset(out, scenes, task, cfg.agents, "test", preset=counts,
                             seed=cfg.seed, eval_agents=eval_agents, progress=cfg.progress)
    digest = hashlib.sha256(b"".join(p.read_bytes() for p in paths)).hexdigest()
    return {"files": [str(p) for p in paths], "sha256": digest}


def _train(args: list[str]) -> dict[str, Any]:
    from collavn.training.trainer import CHECKPOINT, train

    config = parse_train_args(args)
    out = Path(config.run.out)
    resume = (out / CHECKPOINT).is_file()  # interrupted before: continue
    started = out.is_dir() and any(out.iterdir())  # killed before its first checkpoint
    result = train(config.with_run(resume=resume, overwrite=started and not resume))
    return {"iterations": result.iterations, "agent_steps": result.agent_steps,
            "checkpoint": str(result.checkpoint), "resumed": resume,
            "success_rate": result.last.get("episode/success_rate", float("nan"))}


def _evaluation(cfg: ExperimentConfig, name: str, policy: str, dataset: Path, out: Path,
                sizes: list[str]) -> Stage:
    command = ["collavn", "evaluate", "--policy", policy, "--dataset", str(dataset),
               "--out", str(out), "--num-envs", str(cfg.num_envs), "--seed", str(cfg.seed),
               "--device", cfg.device, *sizes]

    def body() -> dict[str, Any]:
        env = PRESETS[cfg.preset][1].env  # checkpoints bring their own image sizes
        ecfg = EvalConfig(policy=policy, dataset=dataset, out=out, num_envs=cfg.num_envs,
                          seed=cfg.seed, device=cfg.device, progress=cfg.progress, env=env)
        result = run_evaluation(ecfg, load_dataset(ecfg))
        report = write_results(out, {name.removeprefix("eval-"): result})
        return {"out": str(out), "records": len(result.records),
                "communication": result.communication.rates(),
                "overall_sr": report.table.rows[0].groups["overall"]["SR"]}

    return Stage(name, command, body)
