"""Free space from a depth panorama: how far the robot's body can drive straight.

The geometry behind the goal-blind explorer (:mod:`collavn.policies.explorer`) and the
``free_space`` sensor (``EnvConfig.free_space``): from each panorama column's nearest
obstacle hit (between floor-bump and robot height), the distance a disc of the robot's
radius can drive along a direction before touching one. It sees only what the panorama
sees (not what lies between two rays or below the camera's view). :class:`ExploreRule`
turns the free runs into the explorer's move, which the ``explore_action`` sensor
(``EnvConfig.explore_action``) reports to a policy.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numba
import numpy as np

from collavn.simulation.kinematics import AgentParams

#: Metres beyond which the ``free_space`` sensor reports no obstacle.
FREE_SPACE_RANGE = 4.0


def panorama_azimuths(width: int) -> np.ndarray:
    """``(W,)`` azimuth of each column relative to the heading (CCW positive)."""
    return 2 * np.pi * (0.5 - np.arange(width) / width)


def obstacle_points(depth: np.ndarray, camera_height: float = 0.9, fov: float = np.pi / 2,
                    band: tuple[float, float] = (0.05, 1.0)) -> np.ndarray:
    """The nearest obstacle hit of each panorama column, ``(..., W, 2)`` (forward, left) m.

    Only the nearest hit of a column matters for :func:`free_runs`: along one azimuth a
    nearer point blocks every direction a farther one does, and sooner. A column with no
    obstacle hit gets ``inf``.

    Args:
        depth: ``(..., H, W)`` distance along each ray in metres (0 = no hit).
        camera_height: Camera height above the floor, metres.
        fov: Vertical field of view, radians.
        band: Heights above the floor between which a hit is an obstacle.
    """
    h, w = depth.shape[-2:]
    elevation = (fov / 2) * (1 - (2 * np.arange(h) + 1) / h)
    height = camera_height + depth * np.sin(elevation)[:, None]
    horizontal = depth * np.cos(elevation)[:, None]
    hit = (depth > 0) & (height > band[0]) & (height < band[1])
    nearest = np.where(hit, horizontal, np.inf).min(axis=-2)
    a = panorama_azimuths(w)
    with np.errstate(invalid="ignore"):  # inf · 0 where a column looks along an axis
        return np.stack([np.where(np.isfinite(nearest), nearest * np.cos(a), np.inf),
                         np.where(np.isfinite(nearest), nearest * np.sin(a), np.inf)], -1)


def free_runs(depth: np.ndarray, radius: float, camera_height: float = 0.9,
              fov: float = np.pi / 2, band: tuple[float, float] = (0.05, 1.0),
              horizon: float = 10.0, directions: int | None = None) -> np.ndarray:
    """``(..., D)`` metres a disc of ``radius`` can drive straight along each direction.

    The directions are every ``W/D``-th panorama column (all ``W`` by default), in
    column order: column ``W/2`` is straight ahead, column 0 straight behind.

    A straight run along direction ``θ`` ends where the disc first touches an obstacle
    point: for a point at ``(along, across)`` in the rotated frame, with
    ``|across| < radius``, contact happens after ``along − √(radius² − across²)``.
    Directions with no obstacle within ``horizon`` metres get ``horizon``.
    """
    width = depth.shape[-1]
    directions = directions or width
    if width % directions:
        raise ValueError(f"free-space directions ({directions}) must divide the panorama "
                         f"width ({width})")
    h = depth.shape[-2]
    elevation = (fov / 2) * (1 - (2 * np.arange(h) + 1) / h)
    a = panorama_azimuths(width)
    theta = a[::width // directions]
    flat = np.ascontiguousarray(depth.reshape(-1, h, width))
    points = np.empty((flat.shape[0], width, 2))
    _points_kernel(flat, np.sin(elevation), np.cos(elevation), np.cos(a), np.sin(a),
                   float(camera_height), float(band[0]), float(band[1]), points)
    runs = np.empty((flat.shape[0], directions))
    _runs_kernel(points, np.cos(theta), np.sin(theta), float(radius), float(horizon), runs)
    return runs.reshape(*depth.shape[:-2], directions)


@numba.njit(cache=True, nogil=True)
def _points_kernel(depth: np.ndarray, sin_e: np.ndarray, cos_e: np.ndarray,
                   cos_a: np.ndarray, sin_a: np.ndarray, camera_height: float, low: float,
                   high: float, points: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`obstacle_points` of ``depth (B, H, W)`` into ``points (B, W, 2)``."""
    for b in range(depth.shape[0]):
        for w in range(depth.shape[2]):
            nearest = np.inf
            for i in range(depth.shape[1]):
                d = np.float64(depth[b, i, w])
                height = camera_height + d * sin_e[i]
                if d > 0 and height > low and height < high:
                    nearest = min(nearest, d * cos_e[i])
            if np.isfinite(nearest):
                points[b, w, 0], points[b, w, 1] = nearest * cos_a[w], nearest * sin_a[w]
            else:
                points[b, w, 0] = points[b, w, 1] = np.inf


@numba.njit(cache=True, nogil=True)
def _runs_kernel(points: np.ndarray, cos: np.ndarray, sin: np.ndarray, radius: float,
                 horizon: float, runs: np.ndarray) -> None:  # pragma: no cover - compiled
    """:func:`free_runs`' minimum over the points ``(B, W, 2)`` into ``runs (B, D)``.

    For each direction ``(cos, sin)`` and seen point (finite) with ``|across| < radius``
    and ``along > 0``: ``along − √(radius² − across²)``; none → ``horizon``; then ≥ 0.
    The same float64 operations in the same order as the array form
    (:func:`free_runs_reference`), so the results are equal, bit for bit (tested).
    """
    r2 = radius * radius
    for b in range(points.shape[0]):
        for d in range(cos.shape[0]):
            c, s = cos[d], sin[d]
            best = horizon
            for w in range(points.shape[1]):
                px, py = points[b, w, 0], points[b, w, 1]
                if not np.isfinite(px):
                    continue
                along = c * px + s * py
                across = -s * px + c * py
                if abs(across) < radius and along > 0:
                    contact = along - np.sqrt(max(r2 - across * across, 0.0))
                    best = min(best, contact)
            runs[b, d] = max(best, 0.0)


def free_runs_reference(depth: np.ndarray, radius: float, camera_height: float = 0.9,
                        fov: float = np.pi / 2, band: tuple[float, float] = (0.05, 1.0),
                        horizon: float = 10.0, directions: int | None = None) -> np.ndarray:
    """:func:`free_runs` in array form (every direction against every column at once).

    The definition the compiled kernel is tested against (~5× slower, measured).
    """
    width = depth.shape[-1]
    directions = directions or width
    points = obstacle_points(depth, camera_height, fov, band)
    seen = np.isfinite(points[..., 0])[..., None, :]  # (..., 1, W)
    px = np.where(seen[..., 0, :], points[..., 0], 0.0)[..., None, :]
    py = np.where(seen[..., 0, :], points[..., 1], 0.0)[..., None, :]
    theta = panorama_azimuths(width)[::width // directions]
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    along = c * px + s * py  # (..., D, W)
    across = -s * px + c * py
    blocking = seen & (np.abs(across) < radius) & (along > 0)  # not beside or behind
    contact = along - np.sqrt(np.maximum(radius**2 - across**2, 0.0))
    run = np.where(blocking, contact, horizon).min(axis=-1, initial=horizon)
    return np.maximum(run, 0.0)


@dataclass(frozen=True)
class ExploreRule:
    """The goal-blind explorer's rule: drive straight while free, else turn to open space.

    Attributes:
        margin: Extra clearance kept from obstacle points, metres (covers the 10 cm
            navigation grid and the gaps between rays).
        min_advance: Drive only if at least this many metres are free ahead.
        open_fraction: A direction is open if its free run is at least this fraction
            of the longest one (1 = only the most open).
        band: Heights above the floor between which a hit is an obstacle (the
            navigation grid's ``step_height`` and ``agent_height``).
    """

    margin: float = 0.12
    min_advance: float = 0.25
    open_fraction: float = 0.8
    band: tuple[float, float] = (0.05, 1.0)

    def free(self, depth: np.ndarray, params: AgentParams, camera_height: float = 0.9,
             fov: float = np.pi / 2) -> np.ndarray:
        """``(..., W)`` free runs of the robot's body plus :attr:`margin`, every column."""
        return free_runs(depth, params.radius + self.margin, camera_height, fov, self.band)

    def moves(self, free: np.ndarray, bumped: np.ndarray, params: AgentParams,
              rngs: Sequence[np.random.Generator] | None = None) -> np.ndarray:
        """``(B, 2)`` actions from free runs ``(B, W)`` and odometry bumps ``(B,)``.

        A clear way ahead (at least :attr:`min_advance`) and no bump: full speed, or
        just short of the obstacle when that is nearer than one step's travel. Else a
        turn in place towards an open direction — away from straight ahead after a
        bump (the last drive fell short: something the panorama does not show), and
        not the half-turn back when any other is open. ``rngs`` (one per row) choose
        among the open directions at random; without them the open direction nearest
        the heading is taken (the left one of a tie), so the move is a function of the
        depth and the bump alone.
        """
        free = np.asarray(free, dtype=np.float64)
        bumped = np.asarray(bumped, dtype=bool)
        width = free.shape[-1]
        azimuth = panorama_azimuths(width)
        ahead = free[:, width // 2]
        drive = (ahead >= self.min_advance) & ~bumped
        allowed = np.where(bumped[:, None], np.abs(azimuth) >= np.pi / 4, True)
        longest = np.where(allowed, free, -np.inf).max(axis=1, keepdims=True)
        is_open = allowed & (free >= self.open_fraction * longest)
        front = is_open & (np.abs(azimuth) <= 0.75 * np.pi)
        is_open = np.where(front.any(axis=1, keepdims=True), front, is_open)
        if rngs is None:
            pick = np.where(is_open, np.abs(azimuth), np.inf).argmin(axis=1)
        else:
            pick = np.zeros(len(free), np.int64)
            for b in np.flatnonzero(~drive).tolist():  # draw only for a turn
                pick[b] = rngs[b].choice(np.flatnonzero(is_open[b]))
        step = params.max_linear * params.step_seconds
        turn = np.clip(azimuth[pick] / (params.max_angular * params.step_seconds), -1.0, 1.0)
        return np.where(drive[:, None],
                        np.stack([np.minimum(1.0, ahead / step), np.zeros_like(ahead)], -1),
                        np.stack([np.zeros_like(turn), turn], -1))


def bumped(moved: np.ndarray, expected: np.ndarray) -> np.ndarray:
    """The last drive fell short by more than 1 cm (odometry ``moved`` vs ``expected``, m)."""
    return np.asarray(moved < expected - 0.01)


def expected_drive(actions: np.ndarray, active: np.ndarray, params: AgentParams) -> np.ndarray:
    """``(E, N)`` metres the ``(E, N, 2)`` actions should drive (0 where inactive)."""
    return np.where(active, np.abs(np.clip(actions[..., 0], -1.0, 1.0)) * params.max_linear
                    * params.step_seconds, 0.0)
