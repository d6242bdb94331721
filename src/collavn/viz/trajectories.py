"""Trajectory pictures as in the paper's appendix, and animated episode GIFs.

Maps: the scene's navigation map, starts as blue circles, goals as orange circles
(with the goal view direction, the success radius shaded and the sight distance
dashed), one coloured path per agent, a diamond where the agent first had its goal in
sight (:func:`~collavn.evaluation.runner.first_sightings`: search ends, homing begins),
a star where an agent succeeded and a cross where it did not.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from collavn.evaluation.runner import Trajectory, first_sightings
from collavn.metrics import SIGHT_DISTANCE
from collavn.rendering.frames import AGENT_COLOURS, views_strip
from collavn.scenes.scene import Scene
from collavn.viz.topdown import draw_scene_map

START_COLOUR = "#1f5fbf"
GOAL_COLOUR = "#ff8c1a"


def draw_trajectory(ax: Any, scene: Scene, traj: Trajectory, title: str | None = None,
                    upto: int | None = None) -> list[Any]:
    """Draw one episode on a matplotlib axis (world coordinates) — the one map drawer.

    ``upto``: draw the paths up to step ``upto`` with each robot's body and heading
    there (animation frames); ``None``: the whole episode with an end marker (star:
    reached, cross: not). Returns the artists of the agents (to remove for the next
    frame).
    """
    draw_scene_map(ax, scene, title or traj.episode_id)
    radius = scene.nav.config.agent_radius
    for goal, yaw in zip(np.unique(traj.goals, axis=0), _goal_yaws(traj), strict=True):
        ax.add_patch(_circle(goal, 1.0, GOAL_COLOUR, alpha=0.18))  # success radius
        ax.add_patch(_ring(goal, SIGHT_DISTANCE, GOAL_COLOUR))  # in sight within
        ax.add_patch(_circle(goal, radius * 1.4, GOAL_COLOUR))
        ax.arrow(goal[0], goal[1], 0.5 * np.cos(yaw), 0.5 * np.sin(yaw), width=0.03,
                 color=GOAL_COLOUR, length_includes_head=True)
    for n in range(traj.poses.shape[1]):
        ax.add_patch(_circle(traj.poses[0, n, :2], radius * 1.4, START_COLOUR))
    artists = draw_agents(ax, scene, traj, upto)
    ax.legend(loc="upper right", fontsize=7)
    _zoom(ax, scene, traj)
    return artists


def draw_agents(ax: Any, scene: Scene, traj: Trajectory, upto: int | None,
                sighted: Sequence[int] | None = None) -> list[Any]:
    """Each agent's path (to step ``upto``, or all), first sighting, end marker or body.

    ``sighted``: :func:`sightings` of ``traj`` if already known (an animation draws every
    frame with the same).
    """
    radius = scene.nav.config.agent_radius
    last = len(traj.poses) - 1 if upto is None else upto
    sighted = sightings(scene, traj) if sighted is None else sighted
    artists: list[Any] = []
    for n in range(traj.poses.shape[1]):
        colour = AGENT_COLOURS[n % len(AGENT_COLOURS)] / 255.0
        xy = traj.poses[: last + 1, n, :2]
        artists += ax.plot(xy[:, 0], xy[:, 1], color=colour, linewidth=2, label=f"agent_{n}")
        if 0 <= sighted[n] <= last:
            first = all(not 0 <= s <= last for s in sighted[:n])  # one legend entry
            artists += ax.plot(*xy[sighted[n]], marker="D", markersize=7, color=colour,
                               markeredgecolor="black", linestyle="none",
                               label="goal first in sight" if first else None)
        if upto is None:
            marker = "*" if traj.success[n] else "X"
            artists += ax.plot(xy[-1, 0], xy[-1, 1], marker=marker,
                               markersize=14 if traj.success[n] else 10, color=colour,
                               markeredgecolor="black")
        else:
            yaw = traj.poses[last, n, 2]
            artists.append(ax.add_patch(_circle(xy[-1], radius, colour)))
            artists.append(ax.arrow(xy[-1, 0], xy[-1, 1], 1.6 * radius * np.cos(yaw),
                                    1.6 * radius * np.sin(yaw), width=0.04, color="black",
                                    length_includes_head=True, zorder=4))
    return artists


def sightings(scene: Scene, traj: Trajectory) -> list[int]:
    """Per agent, the first step of ``traj`` with its goal in sight (``-1``: never)."""
    return first_sightings(scene, traj.poses, traj.goals,
                           [len(traj.poses) - 1] * traj.poses.shape[1])


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
                   map_pixels: int = 360) -> list[np.ndarray]:
    """Animation frames: all agents' panoramas and goal images beside the top-down map.

    Args:
        scene: The episode's scene.
        traj: Poses ``(T + 1, N, 3)``.
        panoramas: ``(T + 1, N, 3, H, W)`` uint8 views along the trajectory.
        goals: ``(N, 3, G, G)`` uint8 goal images.
        map_pixels: Side of the map picture in pixels.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(map_pixels / 100, map_pixels / 100), dpi=100)
    moving = draw_trajectory(ax, scene, traj, traj.episode_id, upto=0)
    fig.tight_layout()
    for artist in moving:  # the map without the agents, drawn once (blitting)
        artist.remove()
    fig.canvas.draw()
    background = fig.canvas.copy_from_bbox(fig.bbox)  # type: ignore[attr-defined]
    frames = []
    sighted = sightings(scene, traj)
    for t in range(len(traj.poses)):
        fig.canvas.restore_region(background)  # type: ignore[attr-defined]
        for artist in draw_agents(ax, scene, traj, upto=t, sighted=sighted):
            ax.draw_artist(artist)
            artist.remove()
        top = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()  # type: ignore[attr-defined]
        frames.append(_side_by_side(views_strip(panoramas[t], goals), top))
    plt.close(fig)
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


def _ring(xy: np.ndarray, r: float, colour: Any) -> Any:
    from matplotlib.patches import Circle

    return Circle((float(xy[0]), float(xy[1])), r, edgecolor=colour, fill=False,
                  linestyle="--", linewidth=1.0, zorder=3)


def _zoom(ax: Any, scene: Scene, traj: Trajectory, margin: float = 2.0) -> None:
    pts = np.concatenate([traj.poses[..., :2].reshape(-1, 2), traj.goals])
    lo, hi = pts.min(axis=0) - margin, pts.max(axis=0) + margin
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])


def _side_by_side(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    h = max(left.shape[0], right.shape[0])
    out = np.full((h, left.shape[1] + right.shape[1], 3), 255, np.uint8)
    out[: left.shape[0], : left.shape[1]] = left
    out[: right.shape[0], left.shape[1]:] = right
    return out
