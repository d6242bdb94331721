"""The batched renderer: poses in, panoramas / goal images with depth out.

::

    renderer = Renderer(scene)                          # Embree on the CPU, 2 threads
    out = renderer.render(poses)                        # poses: (B, 3) x, y, yaw
    out.rgb, out.depth                                  # (B, 3, 128, 512), (B, 128, 512)
    goal = renderer.render(goal_poses, camera="goal")   # (B, 3, 128, 128) pinhole

Outputs (see :mod:`collavn.rendering.cameras` for the pixel → ray mapping):

* ``rgb``: ``(B, 3, H, W)`` uint8; pixels that hit nothing are black.
* ``depth``: ``(B, H, W)`` float32, **distance along the ray** in metres (not z-depth)
  from the camera centre; ``0.0`` where the ray hits nothing.
* ``ids`` (on request): ``(B, H, W)`` int32, the scene triangle index hit, ``−1`` for
  nothing, ``−2 − k`` for the body of agent ``k``.

Other agents are drawn as vertical cylinders (:class:`BodySpec`) standing on the
scene's floor, in a colour per agent index; ``exclude`` names each view's own body.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Literal, Protocol

import numpy as np

from collavn.errors import RenderError, SceneWarning
from collavn.rendering.cameras import CameraSpec
from collavn.rendering.embree_backend import EmbreeBackend
from collavn.rendering.shading import BodySpec, Lighting, ShadingTables
from collavn.scenes.scene import Scene

BackendName = Literal["embree", "warp"]
CameraName = Literal["panorama", "goal"]


@dataclass(frozen=True, eq=False)
class RenderOutput:
    """Images of a batch of views.

    Attributes:
        rgb: ``(B, 3, H, W)`` uint8 colour.
        depth: ``(B, H, W)`` float32 distance along each ray in metres; 0 = no hit.
        ids: ``(B, H, W)`` int32 hit ids (triangle, −1 none, −2 − k body of agent k),
            or None when not requested.
    """

    rgb: np.ndarray
    depth: np.ndarray
    ids: np.ndarray | None = None


class Backend(Protocol):
    """What a ray-casting backend provides (see :meth:`EmbreeBackend.render`)."""

    def render(self, cam_dirs: np.ndarray, views: np.ndarray, bodies: np.ndarray,
               skip: np.ndarray, body: np.ndarray, rgb: np.ndarray, depth: np.ndarray,
               ids: np.ndarray | None) -> None:
        """Fill ``rgb (B, 3, N)``, ``depth (B, N)`` and ``ids (B, N)`` for ``B`` views."""

    def close(self) -> None:
        """Release threads or device memory."""


class Renderer:
    """Renders one scene from many poses at once, on the chosen backend."""

    def __init__(self, scene: Scene, *, backend: BackendName = "embree", device: str = "cpu",
                 panorama: CameraSpec | None = None, goal: CameraSpec | None = None,
                 body: BodySpec | None = None, lighting: Lighting | None = None,
                 threads: int = 2, chunk_rays: int = 16384) -> None:
        """Prepare the scene for fast casting (BVH, shading tables, ray directions).

        Args:
            scene: The scene to render.
            backend: ``"embree"`` (CPU; Embree + Numba on ``threads`` threads) or
                ``"warp"`` (NVIDIA Warp; one kernel on ``device``).
            device: ``"cpu"``, or ``"cuda"`` / ``"cuda:N"`` (Warp only).
            panorama: The agents' 360° camera; default 512×128, ±45°, at 0.9 m.
            goal: The goal-image camera; default pinhole 128×128, 90° FOV, at 0.9 m.
            body: Size of the agents' bodies as drawn in other agents' views.
            lighting: Ambient and directional light.
            threads: CPU threads of the Embree backend.
            chunk_rays: Pixels per work item of the Embree backend.

        Raises:
            RenderError: Unknown backend or device, a GPU that is not there, Warp not
                installed, or a bad camera, body or thread count.
        """
        self.scene = scene
        self.cameras = {"panorama": panorama or CameraSpec.panorama(),
                        "goal": goal or CameraSpec.pinhole()}
        for name, spec in self.cameras.items():
            if not isinstance(spec, CameraSpec):
                raise RenderError(f"{name} camera must be a CameraSpec, got {type(spec).__name__}")
        self.body = body or BodySpec()
        if not (self.body.radius > 0 and self.body.height > 0):
            raise RenderError(f"agent body needs a positive radius and height, got {self.body}")
        if not (isinstance(threads, int) and threads >= 1):
            raise RenderError(f"threads must be a positive integer, got {threads!r}")
        if chunk_rays < 1:
            raise RenderError(f"chunk_rays must be positive, got {chunk_rays}")
        self.backend_name = backend
        self.device = device
        tables = ShadingTables.from_scene(scene, lighting or Lighting())
        self._backend: Backend = _make_backend(scene, tables, backend, device, threads, chunk_rays)
        self._dirs = {name: spec.ray_directions() for name, spec in self.cameras.items()}
        self._warned_off_map = False

    def close(self) -> None:
        """Release the backend's threads."""
        self._backend.close()

    def __enter__(self) -> Renderer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def render(self, poses: np.ndarray, camera: CameraName = "panorama",
               agents: np.ndarray | None = None, exclude: np.ndarray | None = None,
               with_ids: bool = False) -> RenderOutput:
        """Render a batch of views.

        Args:
            poses: ``(B, 3)`` camera poses ``x, y, yaw`` (metres, radians CCW from +x).
            camera: ``"panorama"`` or ``"goal"``.
            agents: Bodies to draw: ``(A, 2)`` x, y shared by all views, or
                ``(B, A, 2)`` per view (e.g. each environment's own agents).
            exclude: ``(B,)`` int index of the body not drawn in each view (its own;
                −1 = draw all). Default: every body is drawn.
            with_ids: Also return the ``(B, H, W)`` hit ids.

        Returns:
            The :class:`RenderOutput`; a fresh set of arrays on every call.

        Raises:
            RenderError: Bad shapes, NaN/inf values, an empty batch, an unknown camera or
                an ``exclude`` index outside ``[-1, A)``.
        """
        if camera not in self.cameras:
            raise RenderError(f"unknown camera {camera!r}: use 'panorama' or 'goal'")
        spec = self.cameras[camera]
        pose = _check_poses(poses)
        if not self._warned_off_map:
            self._warned_off_map = _warn_off_map(self.scene, pose)
        bodies, skip = _check_bodies(agents, exclude, len(pose))
        views = np.empty((len(pose), 5), np.float32)
        views[:, 0:2] = pose[:, 0:2]
        views[:, 2] = self.scene.floor_z + spec.mount_height
        views[:, 3] = np.cos(pose[:, 2])
        views[:, 4] = np.sin(pose[:, 2])
        z0 = self.scene.floor_z
        body = np.array([self.body.radius, z0, z0 + self.body.height], np.float32)
        b, h, w = len(pose), spec.height, spec.width
        rgb = np.empty((b, 3, h, w), np.uint8)
        depth = np.empty((b, h, w), np.float32)
        ids = np.empty((b, h, w), np.int32) if with_ids else None
        self._backend.render(self._dirs[camera], views, bodies, skip, body,
                             rgb.reshape(b, 3, h * w), depth.reshape(b, h * w),
                             None if ids is None else ids.reshape(b, h * w))
        return RenderOutput(rgb=rgb, depth=depth, ids=ids)


def _make_backend(scene: Scene, tables: ShadingTables, backend: str, device: str,
                  threads: int, chunk_rays: int) -> Backend:
    """Construct the named backend (both expose ``render`` and ``close``)."""
    if backend == "embree":
        if device != "cpu":
            raise RenderError(f"the embree backend runs on the CPU only (device 'cpu'), got "
                              f"device {device!r}; use backend='warp' for CUDA GPUs")
        return EmbreeBackend(scene, tables, threads=threads, chunk_rays=chunk_rays)
    if backend == "warp":
        try:
            from collavn.rendering.warp_backend import WarpBackend
        except ImportError as e:
            raise RenderError("the warp backend needs NVIDIA Warp: pip install warp-lang "
                              f"(or collavn[gpu]); import failed: {e}") from e
        return WarpBackend(scene, tables, device=device)
    raise RenderError(f"unknown render backend {backend!r}: use 'embree' or 'warp'")


def _check_poses(poses: np.ndarray) -> np.ndarray:
    """Validate ``(B, 3)`` poses; returns them as float64."""
    try:
        pose = np.asarray(poses, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise RenderError(f"poses must be a numeric (B, 3) array: {e}") from None
    if pose.ndim != 2 or pose.shape[1] != 3:
        raise RenderError(f"poses must have shape (B, 3) = x, y, yaw; got {pose.shape}")
    if pose.shape[0] == 0:
        raise RenderError("empty batch: poses has shape (0, 3); render at least one view")
    if not np.isfinite(pose).all():
        bad = int(np.nonzero(~np.isfinite(pose).all(axis=1))[0][0])
        raise RenderError(f"pose {bad} contains NaN or inf: {pose[bad].tolist()}")
    return pose


def _warn_off_map(scene: Scene, pose: np.ndarray) -> bool:
    """Warn if a ``(B, 3)`` pose stands where the scene has no floor; True if it did."""
    nav = scene.nav
    on_floor = nav.lookup(nav.floor, pose[:, :2], outside=False)
    if on_floor.all():
        return False
    k = int(np.argmin(on_floor))
    lo = nav.origin
    hi = lo + np.array(nav.shape[::-1]) * nav.resolution
    warnings.warn(
        f"scene {scene.name!r}: pose {k} at ({pose[k, 0]:.2f}, {pose[k, 1]:.2f}) is off the "
        f"navigable map (no floor there; the map spans x ∈ [{lo[0]:.1f}, {hi[0]:.1f}], "
        f"y ∈ [{lo[1]:.1f}, {hi[1]:.1f}] m), so its view will be mostly black; further "
        f"off-map poses of this renderer are not reported", SceneWarning, stacklevel=3)
    return True


def _check_bodies(agents: np.ndarray | None, exclude: np.ndarray | None,
                  batch: int) -> tuple[np.ndarray, np.ndarray]:
    """Validate bodies and exclusions; returns ``(B, A, 2)`` float32 and ``(B,)`` int64."""
    if agents is None:
        bodies = np.zeros((batch, 0, 2), np.float32)
    else:
        a = np.asarray(agents, dtype=np.float64)
        if a.ndim == 2 and a.shape[1] == 2:
            a = np.broadcast_to(a, (batch, *a.shape))
        if a.ndim != 3 or a.shape[0] != batch or a.shape[2] != 2:
            raise RenderError(f"agents must have shape (A, 2) or (B, A, 2) with B = {batch}, "
                              f"got {np.shape(agents)}")
        if not np.isfinite(a).all():
            raise RenderError("agents positions contain NaN or inf")
        bodies = np.ascontiguousarray(a, dtype=np.float32)
    if exclude is None:
        return bodies, np.full(batch, -1, np.int64)
    skip = np.asarray(exclude)
    if skip.shape != (batch,) or not np.issubdtype(skip.dtype, np.integer):
        raise RenderError(f"exclude must be a ({batch},) integer array, got shape "
                          f"{skip.shape} and dtype {skip.dtype}")
    if skip.size and (skip.min() < -1 or skip.max() >= bodies.shape[1]):
        raise RenderError(f"exclude indices must be in [-1, {bodies.shape[1]}) (the number of "
                          f"agents), got {skip.tolist()}")
    return bodies, skip.astype(np.int64)
