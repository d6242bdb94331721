"""View-independent shading tables and the CPU per-pixel kernels (Numba).

Shading model (both backends compute exactly this, in float32):

* **texture**: the hit's barycentric ``(u, v)`` (weights of corners 1 and 2)
  interpolate the face's corner UVs; coordinates wrap modulo 1 and pick the nearest
  texel ``textures[m, S − 1 − ⌊frac(v)·S⌋, ⌊frac(u)·S⌋]`` (the scene's convention);
* **tint and light**: times ``face_tint / 255`` times the Lambertian factor
  ``ambient + diffuse · |n · L|`` (two-sided, so back faces are lit like front
  faces); both are per face and precomputed once per scene in ``face_color``;
* **agent bodies**: vertical cylinders in a colour per agent index
  (:data:`BODY_PALETTE`), lit with the same Lambertian term and the hit normal;
* the result is rounded to the nearest integer: ``uint8(min(c + 0.5, 255))``.

Pixels whose ray hits nothing are black, depth 0, id −1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from collavn.scenes.navigation import ROBOT_RADIUS
from collavn.scenes.scene import Scene

#: Colours of agent bodies, agent ``k`` uses ``BODY_PALETTE[k % len(BODY_PALETTE)]``.
BODY_PALETTE = np.array([
    (230, 25, 75), (0, 130, 200), (60, 180, 75), (245, 130, 48),
    (145, 30, 180), (70, 240, 240), (255, 225, 25), (240, 50, 230),
], dtype=np.uint8)

F32 = np.float32


@dataclass(frozen=True)
class Lighting:
    """A directional light plus ambient light; no shadows.

    Attributes:
        ambient: Brightness of surfaces facing away from (or edge-on to) the light.
        diffuse: Extra brightness of surfaces facing the light head-on.
        direction: Direction towards the light (normalised internally). Its x and y
            parts differ so that walls along x and along y get different shades.
    """

    ambient: float = 0.45
    diffuse: float = 0.55
    direction: tuple[float, float, float] = (0.45, 0.25, 0.86)

    def as_array(self) -> np.ndarray:
        """``(5,)`` float32: ambient, diffuse, Lx, Ly, Lz (unit vector)."""
        d = np.asarray(self.direction, dtype=np.float64)
        d = d / max(float(np.linalg.norm(d)), 1e-12)
        return np.array([self.ambient, self.diffuse, *d], dtype=np.float32)


@dataclass(frozen=True)
class BodySpec:
    """Shape of the agents' bodies as other agents see them.

    Attributes:
        radius: Cylinder radius in metres (the robot's, :data:`ROBOT_RADIUS`).
        height: Cylinder height above the floor in metres.
    """

    radius: float = ROBOT_RADIUS
    height: float = 0.6


@dataclass(frozen=True, eq=False)
class ShadingTables:
    """Per-scene arrays the kernels read; built once by :meth:`from_scene`.

    Attributes:
        face_uv: ``(F, 6)`` float32 ``uv0, uv1 − uv0, uv2 − uv0`` per face.
        face_color: ``(F, 3)`` float32 ``tint / 255 · lambert`` per face.
        face_material: ``(F,)`` int32 texture index per face.
        textures: ``(M, S, S, 3)`` uint8 textures.
        light: ``(5,)`` float32 from :meth:`Lighting.as_array`.
        palette: ``(K, 3)`` float32 body colours (0–255).
    """

    face_uv: np.ndarray
    face_color: np.ndarray
    face_material: np.ndarray
    textures: np.ndarray
    light: np.ndarray
    palette: np.ndarray

    @classmethod
    def from_scene(cls, scene: Scene, lighting: Lighting) -> ShadingTables:
        """Precompute everything view-independent about the scene's appearance."""
        light = lighting.as_array()
        uv = scene.face_uvs.astype(np.float32)
        face_uv = np.concatenate([uv[:, 0], uv[:, 1] - uv[:, 0], uv[:, 2] - uv[:, 0]], axis=1)
        lam = light[0] + light[1] * np.abs(scene.face_normals @ light[2:])
        color = scene.face_tint.astype(np.float32) / F32(255.0) * lam[:, None].astype(F32)
        return cls(
            face_uv=np.ascontiguousarray(face_uv, dtype=F32),
            face_color=np.ascontiguousarray(color, dtype=F32),
            face_material=np.ascontiguousarray(scene.face_material, dtype=np.int32),
            textures=np.ascontiguousarray(scene.textures, dtype=np.uint8),
            light=light,
            palette=BODY_PALETTE.astype(F32),
        )


@numba.njit(cache=True, nogil=True)
def fill_rays(cam_dirs: np.ndarray, views: np.ndarray, g0: int, origins: np.ndarray,
              dirs: np.ndarray) -> None:  # pragma: no cover - compiled
    """World rays ``g0 : g0 + n`` of a batch, numbered ``g = b · N + p`` (view, pixel).

    Args:
        cam_dirs: ``(N, 3)`` float32 directions in the agent frame.
        views: ``(B, 5)`` float32 ``x, y, z, cos(yaw), sin(yaw)`` per camera.
        g0: First ray of the chunk.
        origins: ``(n, 3)`` float32 output.
        dirs: ``(n, 3)`` float32 output: ``cam_dirs`` rotated by the view's yaw.
    """
    n_pix, n = cam_dirs.shape[0], dirs.shape[0]
    k = 0
    while k < n:  # one run of consecutive pixels of a view per iteration
        b, p0 = divmod(g0 + k, n_pix)
        run = min(n - k, n_pix - p0)
        c, s = views[b, 3], views[b, 4]
        for i in range(run):
            dx, dy = cam_dirs[p0 + i, 0], cam_dirs[p0 + i, 1]
            dirs[k + i, 0] = c * dx - s * dy
            dirs[k + i, 1] = s * dx + c * dy
            dirs[k + i, 2] = cam_dirs[p0 + i, 2]
            origins[k + i, 0] = views[b, 0]
            origins[k + i, 1] = views[b, 1]
            origins[k + i, 2] = views[b, 2]
        k += run


@numba.njit(cache=True, nogil=True, inline="always")
def hit_body(ox, oy, oz, dx, dy, dz, cx, cy, body):  # pragma: no cover - compiled
    """Entry distance of a ray into a closed vertical cylinder, and the normal there.

    ``body`` is ``(radius, z_bottom, z_top)`` float32. Returns ``(t, nx, ny, nz)``
    with ``t = inf`` on a miss (also when the ray starts inside the cylinder).
    """
    r, z0, z1 = body[0], body[1], body[2]
    px, py = ox - cx, oy - cy
    c = px * px + py * py - r * r
    best, nx, ny, nz = F32(np.inf), F32(0.0), F32(0.0), F32(0.0)
    if c <= F32(0.0) and z0 <= oz <= z1:
        return best, nx, ny, nz
    a = dx * dx + dy * dy
    b = px * dx + py * dy
    disc = b * b - a * c
    if a > F32(1e-12) and disc >= F32(0.0) and c > F32(0.0):
        t = (-b - np.sqrt(disc)) / a
        z = oz + t * dz
        if t > F32(0.0) and z0 <= z <= z1:
            best, nx, ny = t, (px + t * dx) / r, (py + t * dy) / r
    if dz != F32(0.0):
        zc = z1 if oz > z1 else z0
        t = (zc - oz) / dz
        qx, qy = px + t * dx, py + t * dy
        if F32(0.0) < t < best and qx * qx + qy * qy <= r * r and (oz > z1 or oz < z0):
            best, nx, ny, nz = t, F32(0.0), F32(0.0), F32(1.0)
    return best, nx, ny, nz


@numba.njit(cache=True, nogil=True, inline="always")
def _texel(f, w1, w2, face_uv, face_material, textures):  # pragma: no cover - compiled
    """Row and column of the texel that a hit on face ``f`` at barycentric ``w1, w2`` samples."""
    size = textures.shape[1]
    u = face_uv[f, 0] + w1 * face_uv[f, 2] + w2 * face_uv[f, 4]
    v = face_uv[f, 1] + w1 * face_uv[f, 3] + w2 * face_uv[f, 5]
    col = min(int((u - np.floor(u)) * size), size - 1)
    row = size - 1 - min(int((v - np.floor(v)) * size), size - 1)
    return row, col


@numba.njit(cache=True, nogil=True)
def shade_chunk(prim, bu, bv, tfar, dirs, g0, views, bodies, skip, body,
                face_uv, face_color, face_material, textures, light, palette,
                rgb, depth, ids, write_ids):  # pragma: no cover - compiled
    """Shade the cast rays ``g0 : g0 + n`` (numbered as in :func:`fill_rays`).

    Args:
        prim: ``(n,)`` int32 triangle hit by each ray (−1: none), from Embree.
        bu: ``(n,)`` float32 barycentric weight of the triangle's corner 1.
        bv: ``(n,)`` float32 barycentric weight of corner 2.
        tfar: ``(n,)`` float32 hit distance.
        dirs: ``(n, 3)`` float32 world ray directions.
        g0: Number of the chunk's first ray.
        views: ``(B, 5)`` float32 cameras as in :func:`fill_rays`.
        bodies: ``(B, A, 2)`` float32 body centres per view.
        skip: ``(B,)`` int64 body not drawn in each view (−1: none).
        body: ``(3,)`` float32 body radius, bottom z, top z.
        face_uv: See :class:`ShadingTables`.
        face_color: See :class:`ShadingTables`.
        face_material: See :class:`ShadingTables`.
        textures: See :class:`ShadingTables`.
        light: See :class:`ShadingTables`.
        palette: See :class:`ShadingTables`.
        rgb: ``(B, 3, N)`` uint8 output.
        depth: ``(B, N)`` float32 output.
        ids: ``(B, N)`` int32 output, written only if ``write_ids``.
        write_ids: Whether to fill ``ids``.
    """
    n_pix = rgb.shape[2]
    for k in range(prim.shape[0]):
        b, p = divmod(g0 + k, n_pix)
        f = prim[k]
        t = tfar[k] if f >= 0 else F32(np.inf)
        hit = -1
        nx = ny = nz = F32(0.0)
        for a in range(bodies.shape[1]):
            if a != skip[b]:
                ta, ax, ay, az = hit_body(views[b, 0], views[b, 1], views[b, 2], dirs[k, 0],
                                          dirs[k, 1], dirs[k, 2], bodies[b, a, 0],
                                          bodies[b, a, 1], body)
                if ta < t:
                    t, hit, nx, ny, nz = ta, a, ax, ay, az
        if hit >= 0:
            lam = light[0] + light[1] * abs(nx * light[2] + ny * light[3] + nz * light[4])
            j = hit % palette.shape[0]
            for ch in range(3):
                rgb[b, ch, p] = np.uint8(min(palette[j, ch] * lam + F32(0.5), F32(255.0)))
        elif f >= 0:
            row, col = _texel(f, bu[k], bv[k], face_uv, face_material, textures)
            m = face_material[f]
            for ch in range(3):
                c = F32(textures[m, row, col, ch]) * face_color[f, ch] + F32(0.5)
                rgb[b, ch, p] = np.uint8(min(c, F32(255.0)))
        else:
            rgb[b, 0, p] = rgb[b, 1, p] = rgb[b, 2, p] = 0
            t = F32(0.0)
        depth[b, p] = t
        if write_ids:
            ids[b, p] = -2 - hit if hit >= 0 else f


def warm_up() -> None:
    """Compile (or load from Numba's cache) the kernels with the renderer's types."""
    n = 2
    cam = np.zeros((n, 3), F32)
    cam[:, 0] = 1.0
    views = np.array([[0, 0, 0.5, 1, 0]], F32)
    origins, dirs = np.zeros((n, 3), F32), np.zeros((n, 3), F32)
    fill_rays(cam, views, 0, origins, dirs)
    tables = ShadingTables(np.zeros((1, 6), F32), np.ones((1, 3), F32), np.zeros(1, np.int32),
                           np.zeros((1, 2, 2, 3), np.uint8), Lighting().as_array(),
                           BODY_PALETTE.astype(F32))
    shade_chunk(np.zeros(n, np.int32), np.zeros(n, F32), np.zeros(n, F32), np.ones(n, F32),
                dirs, 0, views, np.array([[[2.0, 0.0]]], F32), np.full(1, -1, np.int64),
                np.array([0.2, 0, 1], F32),
                tables.face_uv, tables.face_color, tables.face_material, tables.textures,
                tables.light, tables.palette, np.zeros((1, 3, n), np.uint8),
                np.zeros((1, n), F32), np.zeros((1, n), np.int32), True)

