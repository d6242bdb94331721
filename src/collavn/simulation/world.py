"""Batched world state of ``E`` environments × ``N`` agents in one scene.

The :class:`World` owns no randomness, renders nothing and knows no task rules: it
starts episodes from any :class:`Start` (e.g. a dataset ``Episode``), applies actions
through the kinematics, and keeps the per-agent bookkeeping that metrics need. Reward,
success and time limits are the task's: :func:`collavn.tasks.step_world` steps a world
and applies them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from collavn.errors import ActionError, SceneError
from collavn.scenes.scene import Scene
from collavn.simulation.kinematics import AgentParams, drive, overlapping, wrap_angle


class Start(Protocol):
    """Where an episode's agents start and where their goals are (an ``Episode`` is one)."""

    @property
    def episode_id(self) -> str:
        """Names the episode in error messages."""
        ...

    @property
    def num_agents(self) -> int:
        """N."""
        ...

    @property
    def start_positions(self) -> np.ndarray:
        """``(N, 2)`` metres."""
        ...

    @property
    def start_yaws(self) -> np.ndarray:
        """``(N,)`` radians."""
        ...

    @property
    def agent_goals(self) -> np.ndarray:
        """``(N, 2)`` each agent's goal position."""
        ...

    @property
    def agent_goal_yaws(self) -> np.ndarray:
        """``(N,)`` each agent's goal view direction."""
        ...


@dataclass(frozen=True)
class Motion:
    """What one step of driving did, per agent: arrays ``(E, N)``.

    Attributes:
        moving: The agent was running and drove this step.
        collided: It touched the scene or another robot (only where ``moving``).
        prev_distance: Geodesic distance to its goal before the step.
    """

    moving: np.ndarray
    collided: np.ndarray
    prev_distance: np.ndarray


class World:
    """Agents of ``E`` envs in one scene. Arrays are ``(E, N, ...)``.

    Attributes (all per env and agent): ``position (E,N,2)``, ``yaw``, ``goal (E,N,2)``,
    ``goal_yaw``, ``running`` (not yet terminated or truncated), ``success``,
    ``steps`` (steps taken), ``path_length`` (metres driven), ``collisions`` (steps
    with a collision), ``start_distance`` and ``distance`` (geodesic to own goal),
    ``start_position``/``start_yaw`` (odometry frame).
    """

    def __init__(self, scene: Scene, num_envs: int, num_agents: int,
                 params: AgentParams | None = None) -> None:
        if num_envs < 1 or num_agents < 1:
            raise ValueError(f"need at least one env and one agent, got {num_envs}×{num_agents}")
        self.scene = scene
        self.params = params or AgentParams()
        e, n = num_envs, num_agents
        self.num_envs, self.num_agents = e, n
        self.position = np.zeros((e, n, 2))
        self.yaw = np.zeros((e, n))
        self.goal = np.zeros((e, n, 2))
        self.goal_yaw = np.zeros((e, n))
        self.start_position = np.zeros((e, n, 2))
        self.start_yaw = np.zeros((e, n))
        self.running = np.zeros((e, n), dtype=bool)
        self.success = np.zeros((e, n), dtype=bool)
        self.steps = np.zeros((e, n), dtype=np.int64)
        self.path_length = np.zeros((e, n))
        self.collisions = np.zeros((e, n), dtype=np.int64)
        self.start_distance = np.zeros((e, n))
        self.distance = np.zeros((e, n))

    # ------------------------------------------------------------------ reset
    def reset_envs(self, envs: Sequence[int], episodes: Sequence[Start]) -> None:
        """Start ``episodes[i]`` in env ``envs[i]``.

        Raises:
            SceneError: an episode with the wrong number of agents, or whose starts
                overlap the scene or each other.
        """
        for e, ep in zip(envs, episodes, strict=True):
            if ep.num_agents != self.num_agents:
                raise SceneError(f"episode {ep.episode_id} has {ep.num_agents} agents, "
                                 f"the world has {self.num_agents}")
            start = np.asarray(ep.start_positions, dtype=np.float64)
            if not self.scene.nav.is_navigable(start).all():
                raise SceneError(f"episode {ep.episode_id}: a start is not navigable in "
                                 f"{self.scene.name} (does the episode file match the scene?)")
            if overlapping(start[None], self.params.radius).any():
                raise SceneError(f"episode {ep.episode_id}: starting agents overlap")
            self.position[e], self.yaw[e] = start, wrap_angle(ep.start_yaws)
            self.start_position[e], self.start_yaw[e] = start, self.yaw[e]
            self.goal[e], self.goal_yaw[e] = ep.agent_goals, ep.agent_goal_yaws
            self.running[e], self.success[e] = True, False
            self.steps[e], self.path_length[e], self.collisions[e] = 0, 0.0, 0
            d = self._distances(e)
            self.start_distance[e], self.distance[e] = d, d

    # ------------------------------------------------------------------- step
    def step(self, action: np.ndarray) -> Motion:
        """Drive every running agent for one action; update bookkeeping and distances.

        Args:
            action: ``(E, N, 2)`` float; clipped to ``[-1, 1]``.

        Raises:
            ActionError: wrong shape, or NaN/inf (naming env and agent).
        """
        action = check_actions(action, self.num_envs, self.num_agents)
        moving = self.running.copy()
        result = drive(self.scene.nav, self.position, self.yaw, action, moving, self.params)
        self.position, self.yaw = result.position, result.yaw
        self.path_length += result.distance
        collided = result.collided & moving
        self.collisions += collided
        self.steps += moving
        prev = self.distance.copy()
        for e in range(self.num_envs):
            self.distance[e] = self._distances(e)
        return Motion(moving, collided, prev)

    def finish(self, terminated: np.ndarray, truncated: np.ndarray) -> None:
        """Stop the agents that finished this step (``(E, N)`` bool each)."""
        self.success |= terminated
        self.running &= ~(terminated | truncated)

    def _distances(self, e: int) -> np.ndarray:
        out = np.empty(self.num_agents)
        done = np.zeros(self.num_agents, dtype=bool)
        for i in range(self.num_agents):  # once per distinct goal (CommonGoal: once)
            if not done[i]:
                mine = np.all(self.goal[e] == self.goal[e][i], axis=1)
                out[mine] = self.scene.geodesic_field(self.goal[e][i]).distance(
                    self.position[e][mine])
                done |= mine
        return out

    # -------------------------------------------------------------- odometry
    def poses(self) -> np.ndarray:
        """``(E, N, 3)`` world poses ``(x, y, yaw)``."""
        return np.concatenate([self.position, self.yaw[..., None]], axis=-1)

    def relative_to_start(self) -> np.ndarray:
        """``(E, N, 3)`` pose in each agent's own start frame (x forward, y left)."""
        return relative_pose(np.concatenate([self.start_position, self.start_yaw[..., None]],
                                            axis=-1), self.poses())


def relative_pose(frame: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """``pose`` expressed in ``frame``; both ``(..., 3)`` = (x, y, yaw)."""
    d = pose[..., :2] - frame[..., :2]
    c, s = np.cos(frame[..., 2]), np.sin(frame[..., 2])
    return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1],
                     wrap_angle(pose[..., 2] - frame[..., 2])], axis=-1)


def check_actions(action: np.ndarray, num_envs: int, num_agents: int) -> np.ndarray:
    """Validate and clip an ``(E, N, 2)`` action batch.

    Raises:
        ActionError: wrong shape, or a NaN/inf entry (the message names env and agent).
    """
    a = np.asarray(action, dtype=np.float64)
    if a.shape != (num_envs, num_agents, 2):
        raise ActionError(f"actions must have shape ({num_envs}, {num_agents}, 2), "
                          f"got {a.shape}")
    bad = ~np.isfinite(a).all(axis=-1)
    if bad.any():
        e, n = (int(v) for v in np.argwhere(bad)[0])
        raise ActionError(f"action of agent_{n} in env {e} is not finite: {a[e, n].tolist()}")
    return np.clip(a, -1.0, 1.0)
