"""Resuming and fine-tuning: a checkpoint is used only by a run of the same configuration.

The file format (atomic writes, format version) lives in
:mod:`collavn.policies.checkpoint`, which also turns a checkpoint into a policy.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from collavn import configs
from collavn.errors import CheckpointError, ConfigError
from collavn.policies.checkpoint import load_checkpoint
from collavn.training.config import TrainConfig

#: Folder of ``--snapshot-every`` copies inside a run directory.
SNAPSHOTS = "snapshots"


def snapshot_name(agent_steps: int) -> str:
    """The file name of the snapshot kept at ``agent_steps`` (sorts by steps)."""
    return f"checkpoint_{agent_steps:09d}.pt"


def run_snapshots(run_dir: str | Path, from_steps: int | None = None) -> list[Path]:
    """A run directory's ``--snapshot-every`` snapshots from ``from_steps`` agent-steps on.

    ``from_steps=None`` takes the run's second half: the snapshots kept at no fewer
    agent-steps than half the last one's (the usual set to average; with a snapshot
    every sixth of the run, the last four). Returned in order of agent-steps.

    Raises:
        ConfigError: a negative ``from_steps``.
        CheckpointError: no ``snapshots`` folder in ``run_dir``, or no snapshot at or
            after ``from_steps``.
    """
    if from_steps is not None and from_steps < 0:
        raise ConfigError(f"--from-steps must be ≥ 0, got {from_steps}")
    folder = Path(run_dir) / SNAPSHOTS
    if not folder.is_dir():
        raise CheckpointError(f"{run_dir} holds no {SNAPSHOTS}/ folder (a run trained with "
                              f"--snapshot-every N keeps its snapshots there)")
    kept: list[tuple[int, Path]] = []
    for path in folder.glob("checkpoint_*.pt"):
        steps = path.stem.removeprefix("checkpoint_")
        if steps.isdigit():
            kept.append((int(steps), path))
    if not kept:
        raise CheckpointError(f"{folder} holds no snapshots (checkpoint_<agent-steps>.pt)")
    kept.sort()
    start = kept[-1][0] // 2 if from_steps is None else from_steps
    chosen = [path for steps, path in kept if steps >= start]
    if not chosen:
        raise CheckpointError(f"{folder} holds no snapshot at or after {start:,} agent-steps "
                              f"(the last is at {kept[-1][0]:,})")
    return chosen


def saved_config(payload: dict[str, Any], path: str | Path) -> TrainConfig:
    """The :class:`TrainConfig` stored in a checkpoint."""
    try:
        return TrainConfig.from_dict(payload["config"])
    except (ConfigError, KeyError) as e:
        raise CheckpointError(f"checkpoint {path} holds an unreadable config: {e}") from e


def check_config(payload: dict[str, Any], config: TrainConfig, path: str | Path) -> None:
    """Refuse to resume from a checkpoint whose config differs from ``config``."""
    diffs = differences(saved_config(payload, path).identity(), config.identity())
    if diffs:
        raise CheckpointError(f"checkpoint {path} was written by a different configuration "
                              f"({_shown(diffs)}); resume with the same settings or start a "
                              f"new --out directory")


def average_checkpoints(paths: Sequence[str | Path]) -> dict[str, Any]:
    """The uniform average of the model weights of checkpoints of one run.

    Stochastic weight averaging: PPO's policy moves between checkpoints, and its
    success rate with it; the mean of the weights along the end of a run (the
    ``--snapshot-every`` snapshots of its second half, say) is a policy that scores
    less by chance where it happened to stop. The checkpoints must share their
    configuration (the fields that only steer a run, such as ``--total-steps``, aside):
    one run's snapshots, or a run and its continuation. Floating-point weights and
    buffers are averaged in float64 and cast back; integer buffers, the config, the
    counters and the optimizer state are those of the checkpoint with the most
    agent-steps. The payload records its sources under ``averaged_from``.

    Raises:
        CheckpointError: fewer than two paths, an unreadable checkpoint, one written
            by another configuration (naming the fields), or other weight names or
            shapes.
    """
    if len(paths) < 2:
        raise CheckpointError(f"give at least two checkpoints to average, got {len(paths)}")
    payloads = [load_checkpoint(path) for path in paths]
    first = saved_config(payloads[0], paths[0]).identity()
    for path, payload in zip(paths[1:], payloads[1:], strict=True):
        diffs = differences(saved_config(payload, path).identity(), first)
        if diffs:
            raise CheckpointError(f"checkpoint {path} was written by another configuration "
                                  f"than {paths[0]} ({_shown(diffs)}); average the "
                                  f"checkpoints of one run")
        if {k: v.shape for k, v in payload["model"].items()} != {
                k: v.shape for k, v in payloads[0]["model"].items()}:
            raise CheckpointError(f"checkpoint {path} holds other weights than {paths[0]}")
    base = max(payloads, key=lambda p: int(p["agent_steps"]))
    model: dict[str, torch.Tensor] = {}
    for name, value in base["model"].items():
        if torch.is_floating_point(value):
            total = sum(p["model"][name].double() for p in payloads)
            model[name] = (total / len(payloads)).to(value.dtype)
        else:
            model[name] = value
    out = {k: v for k, v in base.items() if k != "format"}
    out["model"] = model
    out["averaged_from"] = [{"path": str(path), "agent_steps": int(p["agent_steps"])}
                            for path, p in zip(paths, payloads, strict=True)]
    return out


def differences(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    """``"key: checkpoint A vs now B"`` for every leaf where two config dicts differ."""
    return [f"{prefix}{path}: checkpoint {json.dumps(va)} vs now {json.dumps(vb)}"
            for path, (va, vb) in configs.differences(a, b).items()]


def _shown(diffs: list[str], most: int = 8) -> str:
    return "; ".join(diffs[:most]) + (" …" if len(diffs) > most else "")
