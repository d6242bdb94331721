"""Trajectory pictures as in the paper's appendix, and animated episode GIFs.

Maps: the scene's navigation map, starts as blue circles, goals as orange circles
(with the goal view direction), one coloured path per agent, a star where an agent
succeeded and a cross where it did not.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from collavn.evaluation.runner import Trajectory
from collavn.rendering.frames import AGENT_COLOURS, views_strip
from collavn.scenes.scene import Scene
from collavn.viz.topdown import draw_scene_map, nav_map_image

START_COLOUR = "#1f5fbf"
GOAL_COLOUR = "#ff8c1a"


def draw_trajectory(ax: Any, scene: Scene, traj: Trajectory, title: str | None = None) -> None:
    """Draw one episode on a matplotlib axis (world coordinates)."""
    draw_scene_map(ax, scene, title or traj.episode_id)
    radius = scene.nav.config.agent_radius
    for goal, yaw in zip(np.unique(traj.goals, axis=0), _goal_yaws(traj), strict=True):
        ax.add_patch(_circle(goal, 1.0, GOAL_COLOUR, alpha=0.18))  # success radius
        ax.add_patch(_circle(goal, radius * 1.4, GOAL_COLOUR))
        ax.arrow(goal[0], goal[1], 0.5 * np.cos(yaw), 0.5 * np.sin(yaw), width=0.03,
                 color=GOAL_COLOUR, length_includes_head=True)
    for n in range(traj.poses.shape[1]):
        colour = AGENT_COLOURS[n % len(AGENT_COLOURS)] / 255.0
        xy = traj.poses[:, n, :2]
        ax.plot(xy[:, 0], xy[:, 1], color=colour, linewidth=2, label=f"agent_{n}")
        ax.add_patch(_circle(xy[0], radius * 1.4, START_COLOUR))
        marker = "*" if traj.success[n] else "X"
        ax.plot(xy[-1, 0], xy[-1, 1], marker=marker, markersize=14 if traj.success[n] else 10,
                color=colour, markeredgecolor="black")
    ax.legend(loc="upper right", fontsize=7)
    _zoom(ax, scene, traj)


def save_trajectory_maps(scene: Scene, trajectories: Sequence[Trajectory], path: str | Path,
                         columns: int = 3) -> Path:
    """A grid of trajectory maps in one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = max(1, int(np.ceil(len(trajectories) / columns)))
    cols = min(columns, max(1, len(trajectories)))
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 5 * rows), dpi=100, squeeze=False)
    for ax in axes.ravel()[len(trajectories):]:
        ax.axis("off")
    for ax, traj in zip(axes.ravel(), trajectories, strict=False):
        status = f"{int(traj.success.sum())}/{len(traj.success)} reached"
        draw_trajectory(ax, scene, traj, f"{traj.episode_id}  ({status})")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path


def episode_frames(scene: Scene, traj: Trajectory, panoramas: np.ndarray, goals: np.ndarray,
                   cell_pixels: int = 3) -> list[np.ndarray]:
    """Animation frames: all agents' panoramas and goal images beside the top-down map.

    Args:
        scene: The episode's scene.
        traj: Poses ``(T + 1, N, 3)``.
        panoramas: ``(T + 1, N, 3, H, W)`` uint8 views along the trajectory.
        goals: ``(N, 3, G, G)`` uint8 goal images.
        cell_pixels: Map pixels per 10 cm cell.
    """
    base = np.repeat(np.repeat((nav_map_image(scene) * 255).astype(np.uint8), cell_pixels, 0),
                     cell_pixels, 1)
    # Crop the map to the episode (plus 2 m) so large buildings stay legible.
    pts = _to_pixel(scene, np.concatenate([traj.poses[..., :2].reshape(-1, 2), traj.goals]),
                    base.shape[0], cell_pixels)
    margin = 2.0 / scene.nav.resolution * cell_pixels
    r0, c0 = np.maximum(pts.min(axis=0) - margin, 0).astype(int)
    r1, c1 = (pts.max(axis=0) + margin).astype(int)
    frames = []
    for t in range(len(traj.poses)):
        top = _draw_map(base.copy(), scene, traj, t, cell_pixels)[r0:r1, c0:c1]
        strip = views_strip(panoramas[t], goals)
        frames.append(_side_by_side(strip, top))
    return frames


def save_episode_gif(frames: Sequence[np.ndarray], path: str | Path, fps: float = 4.0) -> Path:
    """Write frames as a looping GIF."""
    import imageio.v3 as iio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    iio.imwrite(path, np.stack(frames), extension=".gif", duration=1000.0 / fps, loop=0)
    return path


# ------------------------------------------------------------------ internals
def _goal_yaws(traj: Trajectory) -> list[float]:
    _, first = np.unique(traj.goals, axis=0, return_index=True)
    return [float(traj.goal_yaws[i]) for i in first]


def _circle(xy: np.ndarray, r: float, colour: Any, alpha: float = 1.0) -> Any:
    from matplotlib.patches import Circle

    return Circle((float(xy[0]), float(xy[1])), r, color=colour, alpha=alpha, zorder=3)


def _zoom(ax: Any, scene: Scene, traj: Trajectory, margin: float = 2.0) -> None:
    pts = np.concatenate([traj.poses[..., :2].reshape(-1, 2), traj.goals])
    lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])


def _to_pixel(scene: Scene, xy: np.ndarray, image_h: int, cell_pixels: int) -> np.ndarray:
    nav = scene.nav
    col = (xy[..., 0] - nav.origin[0]) / nav.resolution * cell_pixels
    row = image_h - (xy[..., 1] - nav.origin[1]) / nav.resolution * cell_pixels
    return np.stack([row, col], axis=-1)


def _disc(img: np.ndarray, centre: np.ndarray, radius: float, colour: np.ndarray) -> None:
    h, w = img.shape[:2]
    r0, c0 = centre
    rows, cols = np.ogrid[0:h, 0:w]
    img[(rows - r0) ** 2 + (cols - c0) ** 2 <= radius**2] = colour


def _draw_map(img: np.ndarray, scene: Scene, traj: Trajectory, t: int, cp: int) -> np.ndarray:
    h = img.shape[0]
    body = scene.nav.config.agent_radius / scene.nav.resolution * cp
    for goal in np.unique(traj.goals, axis=0):
        _disc(img, _to_pixel(scene, goal, h, cp), body * 1.3, np.array([255, 140, 26]))
    for n in range(traj.poses.shape[1]):
        colour = AGENT_COLOURS[n % len(AGENT_COLOURS)]
        path = _to_pixel(scene, traj.poses[: t + 1, n, :2], h, cp)
        for p in path:
            _disc(img, p, max(1.0, cp / 2), colour)
        _disc(img, _to_pixel(scene, traj.poses[0, n, :2], h, cp), body * 0.8,
              np.array([31, 95, 191]))
        _disc(img, path[-1], body, colour)
        yaw = traj.poses[t, n, 2]
        tip = path[-1] + 1.6 * body * np.array([-np.sin(yaw), np.cos(yaw)])
        _disc(img, tip, max(1.5, body / 3), np.array([0, 0, 0]))
    return img


def _side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    h = max(left.shape[0], right.shape[0])
    out = np.full((h, left.shape[1] + right.shape[1], 3), 255, np.uint8)
    out[: left.shape[0], : left.shape[1]] = left
    out[: right.shape[0], left.shape[1]:] = right
    return out
