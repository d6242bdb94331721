"""Free space from a depth panorama: how far the robot's body can drive straight.

The geometry behind the goal-blind explorer (:mod:`collavn.policies.explorer`) and the
``free_space`` sensor (``EnvConfig.free_space``): from each panorama column's nearest
obstacle hit (between floor-bump and robot height), the distance a disc of the robot's
radius can drive along a direction before touching one. It sees only what the panorama
sees (not what lies between two rays or below the camera's view).
"""

from __future__ import annotations

import numpy as np

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
