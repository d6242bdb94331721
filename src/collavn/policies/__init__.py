"""Policies behind one protocol: random, explorer, the shortest-path oracle, checkpoints.

Training and evaluation both import this package; neither imports the other.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from collavn.errors import CollavnError
from collavn.policies.base import CommStats, Policy, RandomPolicy
from collavn.policies.checkpoint import (
    CheckpointPolicy,
    checkpoint_model_config,
    load_checkpoint,
    load_policy,
    refuse_silent,
)
from collavn.policies.explorer import ExplorerPolicy
from collavn.policies.oracle import OraclePolicy
from collavn.policies.seeker import SeekerPolicy
from collavn.scenes.scene import Scene

#: Policies named by a word (anything else is a checkpoint path).
NAMED_POLICIES = ("random", "explorer", "oracle", "seeker")

__all__ = ["NAMED_POLICIES", "CheckpointPolicy", "CommStats", "ExplorerPolicy", "OraclePolicy",
           "Policy", "RandomPolicy", "SeekerPolicy", "check_mute", "load_policy", "make_policy"]


def check_mute(name: str) -> None:
    """Refuse ``--mute`` for a policy without messages (a named one, a silent checkpoint).

    ``evaluate`` calls it before it touches its output directory.
    """
    if name in NAMED_POLICIES:
        raise CollavnError(f"--mute cuts a checkpoint's messages; the {name} policy sends none")
    if Path(name).exists():
        refuse_silent(checkpoint_model_config(load_checkpoint(name), name), name)


def make_policy(name: str, scenes: Sequence[Scene], seed: int = 0, device: str = "cpu",
                stochastic: bool = False, mute: bool = False) -> tuple[Policy, dict[str, Any]]:
    """A policy by name (``random``, ``explorer``, ``oracle``, ``seeker``) or checkpoint path.

    ``mute`` (checkpoints only) cuts the links between teammates: an ablation.

    Returns:
        The policy and the env overrides it needs (privileged observations, image sizes).
    """
    if mute and name in NAMED_POLICIES:
        check_mute(name)
    if name == "random":
        return RandomPolicy(seed), {}
    if name == "explorer":
        return ExplorerPolicy(seed), {"depth": True}
    if name == "oracle":
        return OraclePolicy(scenes), {"privileged": True}
    if name == "seeker":
        return SeekerPolicy(list(scenes), seed=seed), {"privileged": True, "depth": True}
    if not Path(name).exists():
        raise CollavnError(f"unknown policy {name!r}: use {', '.join(NAMED_POLICIES)} or a "
                           f"checkpoint file")
    return load_policy(name, device=device, stochastic=stochastic, seed=seed, mute=mute)
