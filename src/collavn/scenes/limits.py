"""Size guards: refuse a scene before its size can exhaust memory.

A mesh in the wrong unit (centimetres read as metres) or with one stray vertex far
away turns a house into kilometres, and the navigation grid grows with the square of
that. Both checks run on coordinates only, before anything scene-sized is allocated.

Memory: building a navigation grid peaks at about 200 bytes per cell (ray-cast
buffers, distance transform, labels), so the default 50 M cells is ~10 GB, which
fits a 24 GB machine with room for the rest (at 0.1 m: a 700 × 700 m floor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from collavn.errors import SceneError

#: Peak bytes per navigation-grid cell while the grid is built (measured, rounded up).
BYTES_PER_CELL = 200


@dataclass(frozen=True)
class SizeLimits:
    """The largest scene a load may produce.

    Attributes:
        max_extent: Largest horizontal extent, metres (a stray vertex 2 km away, or
            a large building in centimetres, exceeds it).
        max_height: Largest vertical extent, metres: 50 storeys. A single room in
            centimetres (250 "m" tall) or millimetres exceeds it.
        max_grid_cells: Largest navigation grid, cells (rows × columns).
    """

    max_extent: float = 1000.0
    max_height: float = 150.0
    max_grid_cells: int = 50_000_000

    def __post_init__(self) -> None:
        for name in ("max_extent", "max_height"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise SceneError(f"{name} must be a positive number, got {value}")
        if self.max_grid_cells < 1:
            raise SceneError(f"max_grid_cells must be positive, got {self.max_grid_cells}")

    def check_extent(self, vertices: np.ndarray, name: str) -> None:
        """Refuse ``(V, 3)`` vertices (metres, Z up, after scaling) that span too far.

        Raises:
            SceneError: naming the extent in metres and the fix.
        """
        if not np.isfinite(vertices).all():
            raise SceneError(f"{name}: mesh vertices contain NaN or inf")
        extent = vertices.max(axis=0) - vertices.min(axis=0)
        if (extent[:2] > self.max_extent).any() or extent[2] > self.max_height:
            raise SceneError(
                f"{name}: the mesh spans {_metres(extent)} (x × y × z, Z up), beyond the "
                f"limits of {self.max_extent:g} m across and {self.max_height:g} m tall. In "
                f"centimetres or millimetres? load it with scale=0.01 or 0.001 (--scale). "
                f"On its side? choose up_axis (--up-axis). A stray vertex far away? remove "
                f"it. Really this large? raise SizeLimits(max_extent=…, max_height=…)")

    def check_grid(self, shape: tuple[int, int], resolution: float, name: str) -> None:
        """Refuse a navigation grid of ``shape`` ``(H, W)`` cells above the limit.

        Raises:
            SceneError: naming the footprint in metres, the cell count and the fix.
        """
        cells = int(shape[0]) * int(shape[1])
        if cells > self.max_grid_cells:
            footprint = np.array([shape[1], shape[0]], dtype=np.float64) * resolution
            raise SceneError(
                f"{name}: a {_metres(footprint)} floor plan needs a navigation grid of "
                f"{cells:,} cells at {resolution:g} m (about "
                f"{_bytes(cells * BYTES_PER_CELL)} to build), more than the limit of "
                f"{self.max_grid_cells:,}. If the file is in centimetres load it with "
                f"scale=0.01 (--scale 0.01); otherwise raise "
                f"SizeLimits(max_grid_cells=…) on a machine with the memory")


def _metres(extent: np.ndarray) -> str:
    return " × ".join(f"{v:,.1f}" if v < 1e7 else f"{v:.3g}" for v in extent) + " m"


def _bytes(n: float) -> str:
    return f"{n / 1e9:,.0f} GB" if n >= 1e9 else f"{n / 1e6:,.1f} MB"
