"""Animated episode GIFs re-rendered from stored poses, and all of an evaluation's pictures."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from collavn.envs.config import EnvConfig
from collavn.envs.sensors import Sensors
from collavn.evaluation.runner import Trajectory
from collavn.scenes import load_scene
from collavn.scenes.scene import Scene
from collavn.scenes.spec import SceneSpec
from collavn.viz.trajectories import episode_frames, save_episode_gif, save_trajectory_maps


def animate_episode(scene: Scene, traj: Trajectory, path: str | Path,
                    panorama_width: int = 256, fps: float = 4.0) -> Path:
    """All agents' panoramas and goal images beside the top-down map, one frame a step."""
    width = max(4, panorama_width - panorama_width % 4)
    config = EnvConfig(num_agents=traj.poses.shape[1], panorama_width=width,
                       panorama_height=width // 4, goal_size=width // 4)
    sensors = Sensors(scene, config)
    panoramas = sensors.panoramas(traj.poses).rgb  # (T + 1, N, 3, H, W): steps as envs
    goal_poses = np.concatenate([traj.goals, traj.goal_yaws[:, None]], axis=1)[None]
    goals = sensors.goal_images(goal_poses)[0]
    return save_episode_gif(episode_frames(scene, traj, panoramas, goals), path, fps)


def draw_all(trajectories: Sequence[Trajectory], out: Path, gifs: int = 1,
             panorama_width: int = 256) -> list[Path]:
    """Maps (one PNG per scene) and ``gifs`` animations; returns the written paths."""
    written = []
    by_scene: dict[SceneSpec, list[Trajectory]] = {}
    for t in trajectories:
        by_scene.setdefault(t.scene, []).append(t)
    scenes = {source: load_scene(source) for source in by_scene}
    for k, (source, trajs) in enumerate(by_scene.items()):
        name = "trajectories.png" if len(by_scene) == 1 else f"trajectories_{k}.png"
        written.append(save_trajectory_maps(scenes[source], trajs, out / name))
    for t in trajectories[:gifs]:
        safe = t.episode_id.replace("/", "_").replace(":", "-")
        written.append(animate_episode(scenes[t.scene], t, out / f"episode_{safe}.gif",
                                       panorama_width))
    return written
