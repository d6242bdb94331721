"""The goal-belief head's labels and loss (``ModelConfig.goal_belief``).

The head reads the actor's GRU state and says where the goal is: which of ``K``
egocentric sectors holds its straight-line bearing (sector 0 is centred straight ahead,
sectors go counter-clockwise, like yaw) and its ``log(1 + distance)``. Labels come from
privileged observations (``world_pose``, ``goal_position``) of the states a run visits,
so the head learns on the policy's own trajectories — where the frame perception's
one-frame readout is right least often — and its gradient asks the recurrent state to
carry the goal's position from step to step.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor


def belief_labels(world_pose: np.ndarray, goal_position: np.ndarray,
                  sectors: int) -> np.ndarray:
    """``(..., 2)`` float32 labels: the goal's sector and ``log(1 + distance)``.

    Args:
        world_pose: ``(..., 3)`` x, y, yaw of each agent.
        goal_position: ``(..., 2)`` x, y of its goal.
        sectors: ``K``.
    """
    offset = np.asarray(goal_position, np.float64) - np.asarray(world_pose, np.float64)[..., :2]
    bearing = np.arctan2(offset[..., 1], offset[..., 0]) - world_pose[..., 2]
    width = 2 * np.pi / sectors
    sector = np.floor(np.mod(bearing + width / 2, 2 * np.pi) / width) % sectors
    distance = np.log1p(np.hypot(offset[..., 0], offset[..., 1]))
    return np.stack([sector, distance], axis=-1).astype(np.float32)


def belief_loss(output: Tensor, labels: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Cross-entropy of the sector and squared error of the log distance, masked means.

    Args:
        output: ``(..., K + 1)`` the head's sector logits and log distance.
        labels: ``(..., 2)`` from :func:`belief_labels`.
        mask: ``(...)`` bool, the steps that count (active agents).

    Returns:
        The two losses (scalars).
    """
    weight = mask.float()
    count = weight.sum().clamp(min=1.0)
    sector = F.cross_entropy(output[..., :-1].flatten(0, -2), labels[..., 0].long().flatten(),
                             reduction="none").view_as(weight)
    distance = (output[..., -1] - labels[..., 1]) ** 2
    return (sector * weight).sum() / count, (distance * weight).sum() / count


def sector_accuracy(output: Tensor, labels: Tensor, mask: Tensor, slack: int = 1) -> float:
    """Fraction of masked steps whose most likely sector is within ``slack`` of the label."""
    k = output.shape[-1] - 1
    gap = (output[..., :-1].argmax(-1) - labels[..., 0].long()).remainder(k)
    right = torch.minimum(gap, k - gap) <= slack
    return float(right[mask].float().mean()) if bool(mask.any()) else float("nan")
