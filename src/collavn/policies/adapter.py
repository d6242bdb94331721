"""The observation adapter: a vector env's NumPy observations → the model's tensors."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch
from torch import Tensor

from collavn.models.config import ModelConfig

#: Observation entries every policy reads (:func:`policy_keys` adds the optional ones).
POLICY_KEYS = ("panorama", "goal", "pose_delta", "active")


def policy_keys(cfg: ModelConfig) -> tuple[str, ...]:
    """Observation entries a model of ``cfg`` reads.

    ``depth`` for the map or the frame perception, ``free_space`` and
    ``explore_action`` where it reads those sensors (:func:`env_overrides` turns them on).
    """
    return (*POLICY_KEYS, *(("depth",) if cfg.reads_depth else ()),
            *(("free_space",) if cfg.free_space_input else ()),
            *(("explore_action",) if cfg.explore_prior else ()))


def env_overrides(cfg: ModelConfig) -> dict[str, Any]:
    """The ``EnvConfig`` fields a model of ``cfg`` needs: image sizes and its sensors."""
    _, h, w = cfg.panorama_shape
    return {"panorama_width": w, "panorama_height": h, "goal_size": cfg.goal_shape[-1],
            **({"depth": True} if cfg.reads_depth else {}),
            **({"free_space": cfg.free_space_input} if cfg.free_space_input else {}),
            **({"explore_action": True} if cfg.explore_prior else {})}


def obs_to_torch(obs: Mapping[str, np.ndarray], keys: tuple[str, ...],
                 device: torch.device | str) -> dict[str, Tensor]:
    """The model's entries of a numpy observation as tensors on ``device`` (no copy on CPU).

    Raises:
        KeyError: naming the entries the model reads that the observation lacks (and
            the ``EnvConfig`` field that turns them on).
    """
    missing = [k for k in keys if k not in obs]
    if missing:
        raise KeyError(f"the policy reads {', '.join(missing)}, which the observation lacks; "
                       f"make the env with EnvConfig({', '.join(f'{k}=…' for k in missing)}) "
                       f"(load_policy returns the overrides a checkpoint needs)")
    return {k: torch.as_tensor(obs[k]).to(device) for k in keys}


def episode_start(obs: Mapping[str, np.ndarray], device: torch.device | str) -> Tensor:
    """``(E, N)`` bool: the observation is the first of an episode (``step == 0``)."""
    return torch.as_tensor(obs["step"] == 0).to(device)
