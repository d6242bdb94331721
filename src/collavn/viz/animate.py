"""Animated GIF of an episode, re-rendered from its stored poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from collavn.envs.config import EnvConfig
from collavn.envs.sensors import Sensors
from collavn.evaluation.runner import Trajectory
from collavn.scenes.scene import Scene
from collavn.viz.trajectories import episode_frames, save_episode_gif


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
