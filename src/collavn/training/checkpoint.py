"""Checkpoints: written atomically, refused when made by a different configuration.

A checkpoint is one ``torch.save`` file holding the resolved config (as a dict), the
update counter, the model and optimizer states. It is written to a temporary file in
the same directory, flushed and ``fsync``-ed, then renamed over the old one, so a kill
at any moment leaves either the old or the new checkpoint, never a torn one.

:func:`load_policy` turns a checkpoint into an evaluation
:class:`~collavn.evaluation.policies.Policy` (deterministic actions).
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import torch

from collavn.errors import CheckpointError
from collavn.models.policy import ActorCritic
from collavn.models.state import AgentState
from collavn.training.config import TrainConfig
from collavn.training.rollout import episode_start, obs_to_torch, policy_keys

#: Bumped when the checkpoint layout changes.
FORMAT_VERSION = 1


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` to ``path`` atomically (temp file, fsync, rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            torch.save({"format": FORMAT_VERSION, **payload}, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu"
                    ) -> dict[str, Any]:
    """Read a checkpoint; raises :class:`CheckpointError` if it is not one of ours."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        payload = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as e:  # torch raises many kinds on a corrupt file
        raise CheckpointError(f"cannot read checkpoint {path}: {e}") from e
    if not isinstance(payload, dict) or payload.get("format") != FORMAT_VERSION:
        raise CheckpointError(f"{path} is not a collavn training checkpoint "
                              f"(format {FORMAT_VERSION})")
    return payload


def check_config(payload: dict[str, Any], config: TrainConfig, path: str | Path) -> None:
    """Refuse to resume from a checkpoint whose config differs from ``config``."""
    saved = TrainConfig.from_dict(payload["config"]).identity()
    current = config.identity()
    if saved != current:
        diffs = sorted(differences(saved, current))
        shown = "; ".join(diffs[:8]) + (" …" if len(diffs) > 8 else "")
        raise CheckpointError(f"checkpoint {path} was written by a different configuration "
                              f"({shown}); resume with the same settings or start a new "
                              f"--out directory")


def differences(a: Any, b: Any, prefix: str = "") -> list[str]:
    """``"key: checkpoint A vs now B"`` for every leaf where two config dicts differ."""
    if isinstance(a, dict) and isinstance(b, dict):
        out = []
        for k in sorted(set(a) | set(b)):
            out += differences(a.get(k), b.get(k), f"{prefix}{k}.")
        return out
    return [] if a == b else [f"{prefix[:-1]}: checkpoint {json.dumps(a)} vs now {json.dumps(b)}"]


class CheckpointPolicy:
    """A trained :class:`ActorCritic` behind the evaluation ``Policy`` interface.

    Numpy observations go to torch on the model's device; ``episode_start`` comes from
    ``obs["step"] == 0``; actions are the policy mean clipped to [-1, 1], or with
    ``stochastic`` samples of the Gaussian (from a generator seeded by ``seed``). Works
    for any number of agents (Ad-hoCoop; ``il`` copies).
    """

    def __init__(self, model: ActorCritic, stochastic: bool = False, seed: int = 0) -> None:
        self.model = model.eval()
        self.keys = policy_keys(model.cfg.map.use_depth)
        self.stochastic = stochastic
        self.seed = seed

    def initial_state(self, num_envs: int, num_agents: int) -> AgentState:
        """Zero recurrent state."""
        return self.model.initial_state(num_envs, num_agents)

    def act(self, obs: dict[str, np.ndarray], state: AgentState
            ) -> tuple[np.ndarray, AgentState]:
        """Actions ``(E, N, 2)`` (the mean, or a sample if ``stochastic``), next state."""
        device = self.model.device
        inputs = obs_to_torch(obs, self.keys, device), state, episode_start(obs, device)
        if not self.stochastic:
            out = self.model.act(*inputs, deterministic=True)
            return out.action.cpu().numpy().astype(np.float64), out.state
        # Sampling draws from torch's global generator: reseed it per call (reproducible
        # per seed) inside fork_rng, so the caller's random state is left as it was.
        with torch.random.fork_rng(devices=[device] if device.type == "cuda" else []):
            torch.manual_seed(self.seed)
            self.seed += 1
            out = self.model.act(*inputs)
        return out.action.cpu().numpy().astype(np.float64), out.state


def load_policy(path: str | Path, device: str = "cpu", stochastic: bool = False,
                seed: int = 0) -> tuple[CheckpointPolicy, dict[str, Any]]:
    """A checkpoint as an evaluation policy, plus the env settings it needs.

    Returns:
        The policy and ``EnvConfig`` overrides (image sizes, depth).
    """
    payload = load_checkpoint(path, map_location=device)
    config = TrainConfig.from_dict(payload["config"])
    model = ActorCritic(config.model, device=device)
    model.load_state_dict(payload["model"])
    overrides: dict[str, Any] = {"panorama_width": config.panorama_width,
                                 "panorama_height": config.panorama_height,
                                 "goal_size": config.goal_size}
    if config.model.map.use_depth:
        overrides["depth"] = True
    return CheckpointPolicy(model, stochastic, seed), overrides
