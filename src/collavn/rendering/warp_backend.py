"""GPU-capable backend: one NVIDIA Warp kernel casts, intersects bodies and shades.

The kernel runs one thread per pixel of every view (``dim = (B, N)``) on the
requested device — a CUDA GPU, or the CPU (one core; that is how its tests run
here). It computes exactly the shading of :mod:`collavn.rendering.shading`; the
differential test holds the two backends to the same pixels.
"""

from __future__ import annotations

import numpy as np
import warp as wp

from collavn.errors import RenderError
from collavn.rendering.shading import ShadingTables
from collavn.rendering.warp_kernel import render_kernel
from collavn.scenes.scene import Scene


def check_device(device: str) -> None:
    """Raise :class:`RenderError` unless Warp can run on ``device``."""
    if device == "cpu":
        return
    if device == "cuda" or device.startswith("cuda:"):
        index = 0 if device == "cuda" else device.split(":", 1)[1]
        count = wp.get_cuda_device_count()
        if not str(index).isdigit():
            raise RenderError(f"bad device {device!r}: use 'cpu', 'cuda' or 'cuda:N'")
        if int(index) >= count:
            raise RenderError(f"device {device!r} requested, but Warp finds {count} CUDA "
                              f"GPU(s) on this machine; use device='cpu'")
        return
    raise RenderError(f"unknown device {device!r}: use 'cpu', 'cuda' or 'cuda:N'")


class WarpBackend:
    """Keeps the scene's mesh and tables on ``device`` and launches the kernel."""

    def __init__(self, scene: Scene, tables: ShadingTables, device: str = "cpu") -> None:
        """Upload the scene (BVH built by Warp) and its shading tables to ``device``."""
        check_device(device)
        self.device = device
        self._points: wp.array = wp.array(scene.vertices, dtype=wp.vec3, device=device)
        self._indices: wp.array = wp.array(scene.faces.reshape(-1), dtype=wp.int32, device=device)
        self._mesh = wp.Mesh(points=self._points, indices=self._indices)
        self._tables: list[wp.array] = [wp.array(a, device=device) for a in (
            tables.face_uv, tables.face_color, tables.face_material, tables.textures,
            tables.light, tables.palette)]
        self._cams: dict[int, tuple[np.ndarray, wp.array]] = {}

    def close(self) -> None:
        """Nothing to release beyond what garbage collection frees."""

    def render(self, cam_dirs: np.ndarray, views: np.ndarray, bodies: np.ndarray,
               skip: np.ndarray, body: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
               ids: np.ndarray | None) -> None:
        """Same contract as :meth:`EmbreeBackend.render`."""
        dev = self.device
        cached = self._cams.get(id(cam_dirs))
        if cached is None or cached[0] is not cam_dirs:  # upload each camera's rays once
            cached = self._cams[id(cam_dirs)] = (cam_dirs, wp.array(cam_dirs, dtype=wp.vec3,
                                                                     device=dev))
        cam = cached[1]
        n_bodies = bodies.shape[1]
        if n_bodies == 0:
            bodies = np.zeros((len(views), 1, 2), np.float32)
        shape = (len(views), cam_dirs.shape[0])
        out = (wp.empty((shape[0], 3, shape[1]), dtype=wp.uint8, device=dev),
               wp.empty(shape, dtype=float, device=dev), wp.empty(shape, dtype=int, device=dev))
        wp.launch(render_kernel, dim=shape, device=dev, inputs=[
            self._mesh.id, cam, wp.array(views, dtype=float, device=dev),
            wp.array(bodies, dtype=float, device=dev), n_bodies,
            wp.array(skip.astype(np.int32), dtype=int, device=dev), wp.vec3(*body.tolist()),
            *self._tables, *out])
        rgb[...] = out[0].numpy()
        depth[...] = out[1].numpy()
        if ids is not None:
            ids[...] = out[2].numpy()
