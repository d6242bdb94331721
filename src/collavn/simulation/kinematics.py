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

import numba
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
    moving = np.asarray(moving, dtype=bool)
    v = np.where(moving, action[..., 0] * params.max_linear, 0.0).astype(np.float64)
    w = np.where(moving, action[..., 1] * params.max_angular, 0.0).astype(np.float64)
    pos, heading, distance, collided = _drive(
        nav.navigable, float(nav.origin[0]), float(nav.origin[1]), float(nav.resolution),
        np.array(position, dtype=np.float64), np.array(yaw, dtype=np.float64), v, w,
        ~moving | (v == 0.0), params.substeps, dt, 2 * params.radius)
    return DriveResult(pos, wrap_angle(heading), distance, collided)


@numba.njit(cache=True, nogil=True)
def _drive(navigable: np.ndarray, origin_x: float, origin_y: float, resolution: float,
           pos: np.ndarray, heading: np.ndarray, v: np.ndarray, w: np.ndarray,
           stopped: np.ndarray, substeps: int, dt: float, limit: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The substep loop of :func:`drive`, one env at a time (envs never interact).

    Per substep: turn about the midpoint heading, stop an agent whose move leaves the
    navigable grid, then (≤ N rounds) stop every agent whose own move brought it within
    ``limit`` of another agent's new position and closer than before.
    """
    n_envs, n = v.shape
    h, w_cells = navigable.shape
    distance = np.zeros((n_envs, n))
    collided = np.zeros((n_envs, n), dtype=np.bool_)
    cand = np.empty((n, 2))
    blocked = np.zeros(n, dtype=np.bool_)
    clash = np.zeros(n, dtype=np.bool_)
    for e in range(n_envs):
        for _ in range(substeps):
            for i in range(n):
                mid = heading[e, i] + 0.5 * w[e, i] * dt
                heading[e, i] = heading[e, i] + w[e, i] * dt
                cand[i, 0], cand[i, 1] = pos[e, i, 0], pos[e, i, 1]
                blocked[i] = False
                if not stopped[e, i]:
                    step = v[e, i] * dt
                    x = pos[e, i, 0] + step * np.cos(mid)
                    y = pos[e, i, 1] + step * np.sin(mid)
                    c = int(np.floor((x - origin_x) / resolution))
                    r = int(np.floor((y - origin_y) / resolution))
                    if 0 <= r < h and 0 <= c < w_cells and navigable[r, c]:
                        cand[i, 0], cand[i, 1] = x, y
                    else:
                        blocked[i] = True
            for _ in range(n):
                any_clash = False
                for i in range(n):
                    clash[i] = False
                    if stopped[e, i] or blocked[i]:
                        continue
                    for j in range(n):
                        if j == i:
                            continue
                        dx, dy = cand[i, 0] - cand[j, 0], cand[i, 1] - cand[j, 1]
                        new = np.sqrt(dx * dx + dy * dy)
                        dx, dy = pos[e, i, 0] - cand[j, 0], pos[e, i, 1] - cand[j, 1]
                        if new < limit and new < np.sqrt(dx * dx + dy * dy):
                            clash[i] = True
                            any_clash = True
                            break
                if not any_clash:
                    break
                for i in range(n):
                    if clash[i]:
                        blocked[i] = True
                        cand[i, 0], cand[i, 1] = pos[e, i, 0], pos[e, i, 1]
            for i in range(n):
                if not (blocked[i] or stopped[e, i]):
                    distance[e, i] += abs(v[e, i]) * dt
                collided[e, i] |= blocked[i]
                stopped[e, i] |= blocked[i]
                pos[e, i, 0], pos[e, i, 1] = cand[i, 0], cand[i, 1]
    return pos, heading, distance, collided
