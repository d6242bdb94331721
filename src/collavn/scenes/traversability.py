"""Traversability from geometry: where there is floor, and where something blocks.

Both functions rasterise onto the navigation grid (see :mod:`collavn.scenes.navigation`
for the cell convention) and are used only when a :class:`NavGrid` is built.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collavn.scenes.navigation import NavConfig


def floor_cells(triangles: np.ndarray, floor_z: float, origin: np.ndarray,
                 shape: tuple[int, int], config: NavConfig) -> np.ndarray:
    """Cells with floor underfoot and headroom above, at ≥ 2 of 4 sample points.

    A vertical ray from just above the floor must hit a surface within a few
    centimetres going down, and nothing below ``agent_height`` going up (this rules
    out space under table tops). A cell is inside a closed solid (a wardrobe taller
    than the robot) when its upward ray meets the back of an upward-facing surface
    *and* horizontal rays meet the backs of surfaces all around; a ceiling seen from
    behind (a suspended grid of one-sided panels) fails the second test, because the
    room's walls face the cell.

    Returns:
        ``(H, W)`` bool.
    """
    import embreex.mesh_construction as mesh_construction
    import embreex.rtcore_scene as rtcore_scene

    scene = rtcore_scene.EmbreeScene()
    mesh_construction.TriangleMesh(scene, np.ascontiguousarray(triangles, dtype=np.float32))
    h, w = shape
    res = config.resolution
    rows, cols = np.mgrid[0:h, 0:w]
    z0 = floor_z + config.step_height - 0.01
    good = np.zeros(h * w, dtype=np.int32)
    looks_up_at_back = np.zeros(h * w, dtype=np.int32)
    up = np.array([0.0, 0.0, 1.0], dtype=np.float32)
    for oy in (0.25 * res, 0.75 * res):
        for ox in (0.25 * res, 0.75 * res):
            o = np.stack([origin[0] + cols.ravel() * res + ox,
                          origin[1] + rows.ravel() * res + oy,
                          np.full(h * w, z0)], axis=1).astype(np.float32)
            below = scene.run(o, np.broadcast_to(-up, o.shape).copy(), output=1)
            above = scene.run(o, np.broadcast_to(up, o.shape).copy(), output=1)
            floor = (below["geomID"] >= 0) & (below["tfar"] <= config.step_height + 0.1)
            clear = (above["geomID"] < 0) | (above["tfar"] > config.agent_height - 0.04)
            good += floor & clear
            looks_up_at_back += (above["geomID"] >= 0) & (above["Ng"][:, 2] > 0)
    good_cells = good >= 2
    candidates = np.nonzero(good_cells & (looks_up_at_back >= 2))[0]
    solid = np.zeros(h * w, dtype=bool)
    centres = np.stack([origin[0] + (cols.ravel()[candidates] + 0.5) * res,
                        origin[1] + (rows.ravel()[candidates] + 0.5) * res], axis=1)
    solid[candidates] = _enclosed(scene, centres, floor_z + 0.5 * config.agent_height)
    # Scans with inverted ceilings would look "inside" everywhere: ignore the rule then.
    if (good_cells & ~solid).sum() >= 0.2 * good_cells.sum():
        good_cells &= ~solid
    return good_cells.reshape(shape)


def _enclosed(scene: Any, xy: np.ndarray, z: float) -> np.ndarray:
    """Whether horizontal rays from ``(P, 2)`` points at height ``z`` all hit back faces.

    Four rays (±x, ±y); a point is enclosed when every ray hits a surface and at
    least three of them see its back (its normal points away from the point).
    """
    if len(xy) == 0:
        return np.zeros(0, dtype=bool)
    backs = np.zeros(len(xy), dtype=np.int32)
    hits = np.zeros(len(xy), dtype=np.int32)
    o = np.concatenate([xy, np.full((len(xy), 1), z)], axis=1).astype(np.float32)
    for d in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        direction = np.tile(np.array([d[0], d[1], 0.0], dtype=np.float32), (len(xy), 1))
        out = scene.run(o, direction, output=1)
        hit = out["geomID"] >= 0
        hits += hit
        backs += hit & ((out["Ng"] * direction).sum(axis=1) > 0)
    return (hits == 4) & (backs >= 3)


def obstacle_cells(triangles: np.ndarray, floor_z: float, origin: np.ndarray,
                    shape: tuple[int, int], config: NavConfig) -> np.ndarray:
    """Cells containing any surface point in the robot's height band.

    Vertical triangles (walls) only need their footprint, a line: they are sampled
    along segments between the corners of their intersection with the band.
    Other triangles are sampled over their area.
    """
    lo, hi = floor_z + config.step_height, floor_z + config.agent_height
    tz = triangles[:, :, 2]
    band = triangles[(tz.max(axis=1) >= lo) & (tz.min(axis=1) <= hi)].astype(np.float64)
    blocked = np.zeros(shape, dtype=bool)
    if len(band) == 0:
        return blocked
    n = np.cross(band[:, 1] - band[:, 0], band[:, 2] - band[:, 0])
    norm = np.linalg.norm(n, axis=1)
    vertical = np.abs(n[:, 2]) <= 0.05 * np.maximum(norm, 1e-12)
    # A face lying exactly on a cell boundary belongs to the cell behind it (inside the
    # solid, or inside the wall of a single-sided scan whose normals face the room).
    # Likewise an edge on a boundary: shrink every triangle a hair towards its centre.
    inward = band.mean(axis=1, keepdims=True) - band
    inward /= np.maximum(np.linalg.norm(inward, axis=2, keepdims=True), 1e-12)
    band = band + 1e-4 * (inward - (n / np.maximum(norm, 1e-12)[:, None])[:, None, :])
    points = [_sample_area(band[~vertical], config.sample_step, lo, hi),
              _sample_footprint(band[vertical], config.sample_step, lo, hi)]
    pts = np.concatenate(points)
    res = config.resolution
    c = np.floor((pts[:, 0] - origin[0]) / res).astype(np.int64)
    r = np.floor((pts[:, 1] - origin[1]) / res).astype(np.int64)
    ok = (r >= 0) & (r < shape[0]) & (c >= 0) & (c < shape[1])
    blocked[r[ok], c[ok]] = True
    return blocked


def _sample_area(tri: np.ndarray, step: float, lo: float, hi: float) -> np.ndarray:
    """Points on a barycentric grid of spacing ≤ ``step`` inside the band, ``(P, 2)``."""
    out = [np.zeros((0, 2))]
    if len(tri) == 0:
        return out[0]
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    longest = np.max(np.linalg.norm(np.stack([e1, e2, tri[:, 2] - tri[:, 1]]), axis=2), axis=0)
    n = np.clip(np.ceil(longest / step), 1, None).astype(np.int64)
    for k in np.unique(n):
        sel = n == k
        i, j = np.nonzero(np.add.outer(np.arange(k + 1), np.arange(k + 1)) <= k)
        a, b = i / k, j / k
        pts = (tri[sel, None, 0] + a[None, :, None] * e1[sel, None]
               + b[None, :, None] * e2[sel, None]).reshape(-1, 3)
        out.append(pts[(pts[:, 2] >= lo) & (pts[:, 2] <= hi), :2])
    return np.concatenate(out)


def _sample_footprint(tri: np.ndarray, step: float, lo: float, hi: float) -> np.ndarray:
    """Points along the xy footprint of vertical triangles clipped to the band."""
    if len(tri) == 0:
        return np.zeros((0, 2))
    # Corners of triangle ∩ slab: corners inside the band, and edge/plane crossings.
    cand, valid = [tri], [(tri[:, :, 2] >= lo) & (tri[:, :, 2] <= hi)]
    for a, b in ((0, 1), (1, 2), (2, 0)):
        pa, pb = tri[:, a], tri[:, b]
        dz = pb[:, 2] - pa[:, 2]
        for plane in (lo, hi):
            with np.errstate(divide="ignore", invalid="ignore"):
                t = (plane - pa[:, 2]) / dz
            ok = (dz != 0) & (t >= 0) & (t <= 1)
            cand.append((pa + np.where(ok, t, 0)[:, None] * (pb - pa))[:, None])
            valid.append(ok[:, None])
    pts = np.concatenate(cand, axis=1)[:, :, :2]  # (T, 9, 2)
    ok = np.concatenate(valid, axis=1)
    i, j = np.triu_indices(pts.shape[1], k=1)
    seg_ok = ok[:, i] & ok[:, j]
    p0, p1 = pts[:, i][seg_ok], pts[:, j][seg_ok]
    counts = np.ceil(np.linalg.norm(p1 - p0, axis=1) / step).astype(np.int64) + 1
    seg = np.repeat(np.arange(len(p0)), counts)
    first = np.cumsum(counts) - counts
    t = (np.arange(counts.sum()) - first[seg]) / np.maximum(counts[seg] - 1, 1)
    return p0[seg] + t[:, None] * (p1[seg] - p0[seg])
