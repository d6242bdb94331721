"""Perception labels the simulator knows exactly, for one scene, as pure functions.

Angles are egocentric and expressed as **panorama columns** (continuous, in ``[0, W)``):
the renderer's column ``j`` looks along azimuth ``2π (1/2 − j/W)`` relative to the
heading (``W/2`` straight ahead, increasing clockwise; see
:mod:`collavn.rendering.cameras`). A label in columns moves with the image: rolling the
panorama by ``k`` columns adds ``k`` to every column label, and mirroring it maps ``c``
to ``W − c``. Bins are image sectors: ``bin(c) = ⌊c K / W⌋``.

* :func:`path_columns` — where the **shortest path** leaves the agent: the point at
  ``reach`` metres, in straight navigable view, that is geodesically nearest the goal
  (what the oracle steers to). The label that makes navigation easiest: turning towards
  it and driving is the expert's policy.
* :func:`goal_columns` — the straight-line bearing of the goal (it agrees with the path
  in open space; where the goal image's content is, when visible).
* :func:`geodesic_distances` — metres through navigable space (``inf``: unreachable).
* :func:`free_space` — per column, how far the robot's centre can drive straight before
  leaving navigable space: what keeps a policy from pushing into walls.
"""

from __future__ import annotations

import numpy as np

from collavn.scenes.navigation import GeodesicField, NavGrid


def column_of(angle: np.ndarray, width: int) -> np.ndarray:
    """Continuous panorama column of egocentric angles (radians, CCW from the heading)."""
    return np.mod(width * (0.5 - np.asarray(angle) / (2 * np.pi)), width)


def angle_of(column: np.ndarray, width: int) -> np.ndarray:
    """Egocentric angle in ``(-π, π]`` of a (continuous) panorama column."""
    a = 2 * np.pi * (0.5 - np.asarray(column, dtype=np.float64) / width)
    return np.mod(a + np.pi, 2 * np.pi) - np.pi


def column_bins(column: np.ndarray, width: int, bins: int) -> np.ndarray:
    """Sector index ``⌊c K / W⌋`` of continuous columns (int64)."""
    return np.floor(np.mod(column, width) * bins / width).astype(np.int64) % bins


def geodesic_distances(field: GeodesicField, positions: np.ndarray) -> np.ndarray:
    """``(B,)`` metres from ``(B, 2)`` positions to the field's goal (``inf``: cut off)."""
    return field.distance(np.asarray(positions, dtype=np.float64))


def goal_columns(positions: np.ndarray, yaws: np.ndarray, goal: np.ndarray,
                 width: int) -> np.ndarray:
    """``(B,)`` column of the straight-line direction to ``goal``."""
    d = np.asarray(goal, dtype=np.float64) - positions
    return column_of(np.arctan2(d[:, 1], d[:, 0]) - yaws, width)


def _in_view(nav: NavGrid, start: np.ndarray, end: np.ndarray, samples: int) -> np.ndarray:
    """``(...)`` the segments ``start → end`` (both ``(..., 2)``) stay navigable."""
    s = np.linspace(0.0, 1.0, samples)[:, None]
    pts = start[..., None, :] + s * (end - start)[..., None, :]
    return np.asarray(np.asarray(nav.is_navigable(pts)).all(axis=-1))


def path_columns(field: GeodesicField, positions: np.ndarray, yaws: np.ndarray,
                 width: int, reach: float = 0.5, directions: int = 72) -> np.ndarray:
    """``(B,)`` column of the shortest path's direction (NaN where the goal is unreachable).

    Among ``directions`` points at ``reach`` metres whose straight segment stays
    navigable, the one with the smallest geodesic distance; within ``reach`` of the goal,
    the goal itself.
    """
    nav = field.nav
    pos = np.asarray(positions, dtype=np.float64)
    angles = np.linspace(-np.pi, np.pi, directions, endpoint=False)
    ring = pos[:, None, :] + reach * np.stack([np.cos(angles), np.sin(angles)], -1)[None]
    step = max(2, int(np.ceil(reach / (0.5 * nav.resolution))) + 1)
    ok = _in_view(nav, np.broadcast_to(pos[:, None, :], ring.shape), ring, step)
    dist = np.where(ok, field.distance(ring), np.inf)
    best = angles[np.argmin(dist, axis=1)]
    out = column_of(best - yaws, width)
    here = geodesic_distances(field, pos)
    near = np.linalg.norm(field.goal - pos, axis=1) <= reach
    out = np.where(near, goal_columns(pos, yaws, field.goal, width), out)
    return np.where(np.isfinite(here) & (np.isfinite(dist).any(axis=1) | near), out, np.nan)


def free_space(nav: NavGrid, positions: np.ndarray, yaws: np.ndarray, width: int,
               max_range: float) -> np.ndarray:
    """``(B, W)`` metres the robot centre can drive along each column's direction.

    Marched in steps of half a navigation cell; ``max_range`` where nothing blocks.
    """
    pos = np.asarray(positions, dtype=np.float64)
    az = angle_of(np.arange(width), width)[None, :] + np.asarray(yaws)[:, None]  # (B, W)
    steps = np.arange(0.5 * nav.resolution, max_range + 1e-9, 0.5 * nav.resolution)
    direction = np.stack([np.cos(az), np.sin(az)], -1)  # (B, W, 2)
    pts = pos[:, None, None, :] + steps[None, None, :, None] * direction[:, :, None, :]
    blocked = ~nav.is_navigable(pts)  # (B, W, S)
    first = np.argmax(blocked, axis=-1)  # index of the first blocked step
    reached = np.concatenate([[0.0], steps[:-1]])[first]  # the last free step before it
    return np.where(blocked.any(-1), reached, max_range).astype(np.float32)


def sector_min(per_column: np.ndarray, bins: int) -> np.ndarray:
    """``(..., W)`` → ``(..., K)``: the minimum over each sector's columns."""
    w = per_column.shape[-1]
    if w % bins:
        raise ValueError(f"panorama width {w} is not a multiple of {bins} bins")
    return per_column.reshape(*per_column.shape[:-1], bins, w // bins).min(-1)
