"""Camera models: which ray each pixel casts, in the agent's own frame.

Agent frame: +x forward (the heading), +y to the agent's left, +z up; the camera sits
``mount_height`` metres above the scene's floor. A pose ``(x, y, yaw)`` places the
agent in the world (yaw in radians, counter-clockwise from world +x); rendering a
pose only rotates the precomputed directions about z, it never rebuilds them.

**Panorama** (cylindrical, 360° horizontally). Pixel ``(row i, column j)`` of a
``W × H`` image looks along azimuth and elevation (angles relative to the heading)::

    azimuth(j)   = 2π · (1/2 − j / W)                  # radians, CCW = to the left
    elevation(i) = (fov / 2) · (1 − (2i + 1) / H)       # radians, up is positive

so column ``W/2`` looks exactly along the heading, image x increases clockwise (to
the agent's right), column 0 looks straight back, and the rows are sampled at pixel
centres uniformly in elevation angle over ``[−fov/2, +fov/2]`` (no row lies on the
horizon; rows ``H/2 − 1`` and ``H/2`` straddle it). A yaw change of ``+Δ`` (turning
left) shifts the image right by ``Δ · W / 2π`` columns: 90° is exactly ``W/4``.

**Pinhole** (goal images). ``fov`` is the horizontal field of view; pixels are
square, so the vertical one is ``2·atan(tan(fov/2)·H/W)``. With the focal length
``f = (W/2) / tan(fov/2)`` pixel ``(i, j)`` looks along the (normalised) direction::

    (f,  W/2 − (j + 1/2),  H/2 − (i + 1/2))            # (forward, left, up)

Directions are unit vectors, so a ray's hit distance ``t`` is the Euclidean distance
from the camera centre (the renderer's depth).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from collavn.errors import RenderError

CameraKind = Literal["panorama", "pinhole"]


#: Largest image a camera may have, pixels (8192×2048: ~2 GB of ray buffers per view).
MAX_PIXELS = 8192 * 2048


@dataclass(frozen=True)
class CameraSpec:
    """Geometry of one camera model.

    Attributes:
        kind: ``"panorama"`` (cylindrical, 360° wide) or ``"pinhole"``.
        width: Image width ``W`` in pixels.
        height: Image height ``H`` in pixels.
        fov_deg: Panorama: vertical field of view (the horizontal one is always 360°);
            pinhole: horizontal field of view. Degrees.
        mount_height: Camera height above the scene's ``floor_z`` in metres.
    """

    kind: CameraKind = "panorama"
    width: int = 512
    height: int = 128
    fov_deg: float = 90.0
    mount_height: float = 0.9

    def __post_init__(self) -> None:
        if self.kind not in ("panorama", "pinhole"):
            raise RenderError(f"unknown camera kind {self.kind!r}: use 'panorama' or 'pinhole'")
        if not all(isinstance(v, int | np.integer) for v in (self.width, self.height)):
            raise RenderError(f"camera size must be integers, got {self.width}×{self.height}")
        if self.width < 1 or self.height < 1:
            raise RenderError(f"camera size must be positive, got {self.width}×{self.height}")
        if self.width * self.height > MAX_PIXELS:
            raise RenderError(f"a {self.width}×{self.height} image has "
                              f"{self.width * self.height:,} pixels, more than the limit of "
                              f"{MAX_PIXELS:,} (e.g. 8192×2048)")
        if self.kind == "panorama" and self.width % 4:
            raise RenderError(f"panorama width must be a multiple of 4 (so that 90° is a whole "
                              f"number of columns), got {self.width}")
        if not 0.0 < self.fov_deg < 180.0:
            raise RenderError(f"field of view must be in (0, 180) degrees, got {self.fov_deg}")
        if not (math.isfinite(self.mount_height) and self.mount_height > 0):
            raise RenderError(f"camera mount height must be positive, got {self.mount_height}")

    @classmethod
    def panorama(cls, width: int = 512, height: int = 128, fov_deg: float = 90.0,
                 mount_height: float = 0.9) -> CameraSpec:
        """The agent's 360° sensor (default ``3×128×512``, ±45° vertically)."""
        return cls("panorama", width, height, fov_deg, mount_height)

    @classmethod
    def pinhole(cls, width: int = 128, height: int = 128, fov_deg: float = 90.0,
                mount_height: float = 0.9) -> CameraSpec:
        """A forward-looking perspective camera (goal images: 128×128, 90°)."""
        return cls("pinhole", width, height, fov_deg, mount_height)

    @property
    def num_pixels(self) -> int:
        """``H · W``."""
        return self.width * self.height

    def ray_directions(self) -> np.ndarray:
        """Unit ray direction of every pixel in the agent frame.

        Returns:
            ``(H·W, 3)`` float32, row-major over ``(H, W)``: (forward, left, up).
        """
        w, h = self.width, self.height
        fov = math.radians(self.fov_deg)
        if self.kind == "panorama":
            azimuth = 2.0 * np.pi * (0.5 - np.arange(w) / w)
            elevation = 0.5 * fov * (1.0 - (2.0 * np.arange(h) + 1.0) / h)
            az, el = np.meshgrid(azimuth, elevation)
            d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], -1)
        else:
            f = 0.5 * w / math.tan(0.5 * fov)
            left = 0.5 * w - (np.arange(w) + 0.5)
            up = 0.5 * h - (np.arange(h) + 0.5)
            lf, uu = np.meshgrid(left, up)
            d = np.stack([np.full_like(lf, f), lf, uu], -1)
            d /= np.linalg.norm(d, axis=-1, keepdims=True)
        return np.ascontiguousarray(d.reshape(-1, 3), dtype=np.float32)
