"""Top-down pictures of a scene: navigable area, obstacles, components, scale bar."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from collavn.scenes.scene import Scene

#: Colours of the map layers (RGB in [0, 1]).
OUTSIDE = (1.0, 1.0, 1.0)
OBSTACLE = (0.25, 0.25, 0.28)
FREE_NOT_NAVIGABLE = (0.72, 0.72, 0.74)
COMPONENT_COLOURS = ((0.62, 0.80, 0.93), (0.99, 0.80, 0.55), (0.70, 0.88, 0.66),
                     (0.85, 0.74, 0.90), (0.96, 0.70, 0.70), (0.85, 0.85, 0.60))


def nav_map_image(scene: Scene) -> np.ndarray:
    """``(H, W, 3)`` float image of the navigation grid, +y up (rows flipped).

    White: no floor. Dark: floor blocked by geometry. Grey: free but too close to an
    obstacle for the robot's centre. Colours: navigable components (largest = blue).
    """
    nav = scene.nav
    img = np.empty((*nav.shape, 3))
    img[:] = OUTSIDE
    img[nav.floor & ~nav.free] = OBSTACLE
    img[nav.free & ~nav.navigable] = FREE_NOT_NAVIGABLE
    for label in range(1, int(nav.components.max()) + 1):
        img[nav.components == label] = COMPONENT_COLOURS[(label - 1) % len(COMPONENT_COLOURS)]
    return img[::-1]


def map_extent(scene: Scene) -> tuple[float, float, float, float]:
    """Matplotlib ``extent`` (left, right, bottom, top) of the map in world metres."""
    nav = scene.nav
    h, w = nav.shape
    x0, y0 = nav.origin
    return (x0, x0 + w * nav.resolution, y0, y0 + h * nav.resolution)


def draw_scene_map(ax: Any, scene: Scene, title: str | None = None) -> None:
    """Draw the navigation map on a matplotlib axis in world coordinates, with scale bar."""
    ax.imshow(nav_map_image(scene), extent=map_extent(scene), interpolation="nearest")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    if title:
        ax.set_title(title)
    left, right, bottom, _top = map_extent(scene)
    length = float(max(1, round((right - left) / 5)))
    x, y = left + 0.04 * (right - left), bottom + 0.04 * (right - left)
    ax.plot([x, x + length], [y, y], color="black", linewidth=3, solid_capstyle="butt")
    ax.text(x + length / 2, y + 0.015 * (right - left), f"{length:g} m", ha="center",
            va="bottom", fontsize=8, clip_on=True)  # a zoomed view hides bar and label


def save_scene_map(scene: Scene, path: str | Path, title: str | None = None) -> Path:
    """Write the top-down map of ``scene`` as a PNG; returns the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    left, right, bottom, top = map_extent(scene)
    aspect = (top - bottom) / max(right - left, 1e-6)
    fig, ax = plt.subplots(figsize=(8, max(3.0, min(12.0, 8 * aspect)) + 0.6), dpi=110)
    draw_scene_map(ax, scene, title or scene.name)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
