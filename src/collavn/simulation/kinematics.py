"""Differential-drive kinematics with collisions, as pure functions over batches.

Shapes: ``E`` environments × ``N`` agents. One action lasts ``step_seconds`` and is
integrated in ``substeps`` pieces (midpoint heading). **Contact rule: stop.** When a
substep would put an agent's centre off the navigable grid (closer than its radius to
the scene), or its own move would bring it closer than two radii to another agent,
that agent does not translate for the rest of the action; its rotation still
completes (a circular body can always turn in place). Such a step counts as a
collision. An agent moving away from a robot it touches is free to go.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from collavn.scenes.navigation import ROBOT_RADIUS, NavGrid


@dataclass(frozen=True)
class AgentParams:
    """The robot (LoCoBot) and the control timing.

    Attributes:
        radius: Body radius in metres (width 0.36 m).
        max_linear: Speed in m/s at action ``a[0] = 1`` (paper: 0.70 m/s).
        max_angular: Turn rate in rad/s at ``a[1] = 1`` (paper: 180 °/s).
        step_seconds: Duration of one action (paper: 1 s).
        substeps: Integration pieces per action; 20 keeps each piece at 3.5 cm,
            below a 10 cm grid cell, so no agent tunnels through a wall.
    """

    radius: float = ROBOT_RADIUS
    max_linear: float = 0.70
    max_angular: float = float(np.pi)
    step_seconds: float = 1.0
    substeps: int = 20


@dataclass(frozen=True)
class DriveResult:
    """Outcome of one action for every agent.

    Attributes:
        position: ``(E, N, 2)`` new positions.
        yaw: ``(E, N)`` new headings in ``(-π, π]``.
        distance: ``(E, N)`` metres actually driven.
        collided: ``(E, N)`` bool, blocked by the scene or another agent.
    """

    position: np.ndarray
    yaw: np.ndarray
    distance: np.ndarray
    collided: np.ndarray


def wrap_angle(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to ``(-π, π]``."""
    return np.pi - np.mod(np.pi - np.asarray(a), 2 * np.pi)


def overlapping(position: np.ndarray, radius: float) -> np.ndarray:
    """``(E, N)`` bool: agent overlaps at least one other agent of its env."""
    d = np.linalg.norm(position[:, :, None] - position[:, None, :], axis=-1)
    n = position.shape[1]
    d[:, np.arange(n), np.arange(n)] = np.inf
    return (d < 2 * radius).any(axis=-1)


def _closing_in(before: np.ndarray, after: np.ndarray, limit: float) -> np.ndarray:
    """``(E, N)``: an agent's own move brought it within ``limit`` of another agent.

    True when it ends closer than ``limit`` to another agent's new position and closer
    than it was before moving (so an agent backing away is never blamed).
    """
    n = after.shape[1]
    new = np.linalg.norm(after[:, :, None] - after[:, None, :], axis=-1)
    old = np.linalg.norm(before[:, :, None] - after[:, None, :], axis=-1)
    new[:, np.arange(n), np.arange(n)] = np.inf
    return ((new < limit) & (new < old)).any(axis=-1)


def drive(nav: NavGrid, position: np.ndarray, yaw: np.ndarray, action: np.ndarray,
          moving: np.ndarray, params: AgentParams) -> DriveResult:
    """Apply one action to every agent of every env of one scene.

    Args:
        nav: The scene's navigation grid (collision geometry).
        position: ``(E, N, 2)`` current positions (valid and non-overlapping).
        yaw: ``(E, N)`` current headings.
        action: ``(E, N, 2)`` in ``[-1, 1]``: (linear, angular) normalised velocity.
        moving: ``(E, N)`` bool; agents that are done stay put (but still block).
        params: Robot and timing.
    """
    dt = params.step_seconds / params.substeps
    v = np.where(moving, action[..., 0] * params.max_linear, 0.0)
    w = np.where(moving, action[..., 1] * params.max_angular, 0.0)
    pos = np.array(position, dtype=np.float64)
    heading = np.array(yaw, dtype=np.float64)
    stopped = ~moving | (v == 0.0)
    collided = np.zeros(moving.shape, dtype=bool)
    distance = np.zeros(moving.shape)
    for _ in range(params.substeps):
        mid = heading + 0.5 * w * dt
        heading = heading + w * dt
        step = (v * dt)[..., None] * np.stack([np.cos(mid), np.sin(mid)], axis=-1)
        candidate = np.where(stopped[..., None], pos, pos + step)
        blocked = ~stopped & ~nav.is_navigable(candidate)
        candidate[blocked] = pos[blocked]
        # Agents moving into each other: an agent whose own move brought it within two
        # radii of another is stopped; repeat until no overlap remains (≤ N rounds).
        for _ in range(pos.shape[1]):
            clash = _closing_in(pos, candidate, 2 * params.radius) & ~stopped & ~blocked
            if not clash.any():
                break
            blocked |= clash
            candidate[clash] = pos[clash]
        distance += np.where(blocked | stopped, 0.0, np.abs(v) * dt)
        collided |= blocked
        stopped |= blocked
        pos = candidate
    return DriveResult(pos, wrap_angle(heading), distance, collided)
