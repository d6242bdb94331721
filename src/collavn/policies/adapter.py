"""The observation adapter: a vector env's NumPy observations → the model's tensors."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch
from torch import Tensor

#: Observation entries a policy reads (``depth`` only when the map uses it).
POLICY_KEYS = ("panorama", "goal", "pose_delta", "active")


def policy_keys(use_depth: bool) -> tuple[str, ...]:
    """Observation entries given to the model."""
    return (*POLICY_KEYS, "depth") if use_depth else POLICY_KEYS


def obs_to_torch(obs: Mapping[str, np.ndarray], keys: tuple[str, ...],
                 device: torch.device | str) -> dict[str, Tensor]:
    """The model's entries of a numpy observation as tensors on ``device`` (no copy on CPU)."""
    return {k: torch.as_tensor(obs[k]).to(device) for k in keys}


def episode_start(obs: Mapping[str, np.ndarray], device: torch.device | str) -> Tensor:
    """``(E, N)`` bool: the observation is the first of an episode (``step == 0``)."""
    return torch.as_tensor(obs["step"] == 0).to(device)
