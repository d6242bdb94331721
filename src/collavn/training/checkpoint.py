"""Resuming and fine-tuning: a checkpoint is used only by a run of the same configuration.

The file format (atomic writes, format version) lives in
:mod:`collavn.policies.checkpoint`, which also turns a checkpoint into a policy.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from collavn import configs
from collavn.errors import CheckpointError, ConfigError
from collavn.training.config import TrainConfig


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


def differences(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    """``"key: checkpoint A vs now B"`` for every leaf where two config dicts differ."""
    return [f"{prefix}{path}: checkpoint {json.dumps(va)} vs now {json.dumps(vb)}"
            for path, (va, vb) in configs.differences(a, b).items()]


def _shown(diffs: list[str], most: int = 8) -> str:
    return "; ".join(diffs[:most]) + (" …" if len(diffs) > most else "")
