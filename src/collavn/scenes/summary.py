"""Facts about a scene as plain values: size, navigable area, components, geodesic span."""

from __future__ import annotations

from typing import Any

import numpy as np

from collavn.scenes.scene import Scene


def scene_summary(scene: Scene) -> dict[str, Any]:
    """Facts about a scene as plain JSON-able values."""
    nav = scene.nav
    sizes = nav.component_sizes()
    lo, hi = scene.bounds
    return {
        "name": scene.name,
        "source": scene.source,
        "triangles": scene.num_triangles,
        "materials": len(scene.textures),
        "bounds_min": [round(float(v), 3) for v in lo],
        "bounds_max": [round(float(v), 3) for v in hi],
        "extent_m": [round(float(v), 2) for v in hi - lo],
        "floor_z": round(scene.floor_z, 3),
        "grid": {"resolution_m": nav.resolution, "rows": nav.shape[0], "cols": nav.shape[1]},
        "navigable_area_m2": round(float(nav.navigable.sum() * nav.resolution**2), 2),
        "components": len(sizes),
        "component_areas_m2": [round(float(a), 2) for a in sizes[:10]],
        "largest_geodesic_m": round(largest_geodesic(scene), 2),
        "content_hash": scene.content_hash,
    }


def largest_geodesic(scene: Scene) -> float:
    """Longest geodesic distance in the largest component (two-sweep estimate).

    Fast marching from any cell, then again from the farthest cell found; the
    second sweep's maximum is the diameter for tree-like floor plans and a tight
    lower bound otherwise.
    """
    nav = scene.nav
    rows, cols = np.nonzero(nav.components == 1)
    start = nav.cell_centers(rows[len(rows) // 2], cols[len(cols) // 2])
    far = 0.0
    for _ in range(2):
        grid = scene.geodesic_field(start).grid
        masked = np.where(np.isfinite(grid), grid, -1.0)
        k = int(np.argmax(masked))
        far = float(masked.flat[k])
        row, col = np.unravel_index(k, grid.shape)
        start = nav.cell_centers(np.asarray(row), np.asarray(col))
    return far
