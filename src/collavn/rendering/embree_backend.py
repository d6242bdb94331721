"""CPU backend: Embree ray casts (``embreex``) plus Numba shading, on a few threads.

The batch's rays are numbered ``g = b · N + p`` (view, pixel) and cut into chunks of
``chunk_rays`` consecutive rays (a chunk may span views: small images batch well);
each thread owns its ray buffers and takes every ``threads``-th chunk. Per chunk the thread
rotates the precomputed camera rays (:func:`fill_rays`), casts them with Embree
(which releases the GIL) and shades them straight into the output arrays
(:func:`shade_chunk`, also GIL-free), so both cores stay busy end to end.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from embreex import mesh_construction, rtcore_scene

from collavn.rendering.shading import ShadingTables, fill_rays, shade_chunk, warm_up
from collavn.scenes.scene import Scene

F32 = np.float32


class EmbreeBackend:
    """Casts with Embree and shades with Numba; see the module docstring."""

    def __init__(self, scene: Scene, tables: ShadingTables, threads: int = 2,
                 chunk_rays: int = 16384) -> None:
        """Build the Embree BVH of ``scene``.

        Args:
            scene: The scene to render.
            tables: Its shading tables.
            threads: Python threads casting and shading in parallel.
            chunk_rays: Pixels per work item (keeps each thread's buffers in cache).
        """
        self._embree = rtcore_scene.EmbreeScene()
        self._mesh = mesh_construction.TriangleMesh(
            self._embree, np.ascontiguousarray(scene.vertices, dtype=F32),
            np.ascontiguousarray(scene.faces, dtype=np.int32))
        self.tables = tables
        self.threads = threads
        self.chunk_rays = chunk_rays
        self._pool = ThreadPoolExecutor(threads) if threads > 1 else None
        warm_up()

    def close(self) -> None:
        """Stop the worker threads."""
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def render(self, cam_dirs: np.ndarray, views: np.ndarray, bodies: np.ndarray,
               skip: np.ndarray, body: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
               ids: np.ndarray | None) -> None:
        """Render every view into the given output arrays.

        Args:
            cam_dirs: ``(N, 3)`` float32 camera ray directions (agent frame).
            views: ``(B, 5)`` float32 ``x, y, z, cos(yaw), sin(yaw)`` per view.
            bodies: ``(B, A, 2)`` float32 body centres visible to each view.
            skip: ``(B,)`` int64 body index not drawn in each view (−1: none).
            body: ``(3,)`` float32 body radius, bottom z, top z.
            rgb: ``(B, 3, N)`` uint8 output.
            depth: ``(B, N)`` float32 output.
            ids: ``(B, N)`` int32 output, or None to skip ids.
        """
        total = cam_dirs.shape[0] * views.shape[0]
        jobs = [(g0, min(g0 + self.chunk_rays, total))
                for g0 in range(0, total, self.chunk_rays)]
        args = (cam_dirs, views, bodies, skip, body, rgb, depth, ids)
        if self._pool is None or len(jobs) == 1:
            self._work(jobs, *args)
            return
        futures = [self._pool.submit(self._work, jobs[k::self.threads], *args)
                   for k in range(self.threads)]
        for future in futures:
            future.result()

    def _work(self, jobs: list[tuple[int, int]], cam_dirs: np.ndarray,
              views: np.ndarray, bodies: np.ndarray, skip: np.ndarray, body: np.ndarray,
              rgb: np.ndarray, depth: np.ndarray, ids: np.ndarray | None) -> None:
        """One thread's share: rotate, cast and shade each chunk."""
        t = self.tables
        size = max(g1 - g0 for g0, g1 in jobs)
        origins, dirs = np.empty((size, 3), F32), np.empty((size, 3), F32)
        id_out = ids if ids is not None else np.empty((1, 1), np.int32)
        for g0, g1 in jobs:
            o, d = origins[: g1 - g0], dirs[: g1 - g0]
            fill_rays(cam_dirs, views, g0, o, d)
            hit = self._embree.run(o, d, output=1)
            shade_chunk(hit["primID"], hit["u"], hit["v"], hit["tfar"], d, g0, views, bodies,
                        skip, body, t.face_uv, t.face_color, t.face_material, t.textures,
                        t.light, t.palette, rgb, depth, id_out, ids is not None)
