"""Policies that need no learning, and the interface every policy follows.

A policy acts for a batch of agents::

    state = policy.initial_state(num_envs, num_agents)
    actions, state = policy.act(obs, state)      # actions: (E, N, 2) in [-1, 1]

``obs`` is the vector env's observation dict (arrays ``(E, N, ...)``); an agent whose
``obs["step"]`` is 0 has just started an episode (reset any memory for it).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import numpy as np

from collavn.scenes.scene import Scene
from collavn.simulation.kinematics import AgentParams, wrap_angle


class Policy(Protocol):
    """Anything with ``initial_state`` and ``act`` over ``(E, N)`` agents."""

    def initial_state(self, num_envs: int, num_agents: int) -> Any:
        """Recurrent state for a fresh batch (``None`` if memoryless)."""
        ...

    def act(self, obs: dict[str, np.ndarray], state: Any) -> tuple[np.ndarray, Any]:
        """``(E, N, 2)`` actions in ``[-1, 1]`` and the next state."""
        ...


class RandomPolicy:
    """Uniform actions in ``[-1, 1]²``, from its own seeded generator."""

    def __init__(self, seed: int = 0) -> None:
        self.rng = np.random.default_rng(seed)

    def initial_state(self, num_envs: int, num_agents: int) -> None:
        """Memoryless."""
        return None

    def act(self, obs: dict[str, np.ndarray], state: None) -> tuple[np.ndarray, None]:
        """Uniform random actions."""
        e, n = obs["active"].shape
        return self.rng.uniform(-1.0, 1.0, (e, n, 2)), None


class OraclePolicy:
    """Follows the geodesic shortest path with the robot's own kinematics.

    Needs privileged observations (``EnvConfig(privileged=True)``): the world pose,
    the goal position and the scene index. Each step it picks the farthest point of
    the shortest path within ``lookahead`` metres that is in straight view on the
    navigable grid, turns towards it and drives as far as the turn allows. It is the
    ceiling a learned agent can hope for on these kinematics.
    """

    def __init__(self, scenes: Sequence[Scene], params: AgentParams | None = None,
                 lookahead: float = 1.2) -> None:
        self.scenes = list(scenes)
        self.params = params or AgentParams()
        self.lookahead = lookahead

    def initial_state(self, num_envs: int, num_agents: int) -> None:
        """Memoryless (paths are recomputed from the current pose)."""
        return None

    def act(self, obs: dict[str, np.ndarray], state: None) -> tuple[np.ndarray, None]:
        """Steer every active agent along its shortest path."""
        if "world_pose" not in obs:
            raise KeyError("the oracle needs privileged observations: "
                           "EnvConfig(privileged=True)")
        pose, goal, active = obs["world_pose"], obs["goal_position"], obs["active"]
        actions = np.zeros((*active.shape, 2))
        for e, n in zip(*np.nonzero(active), strict=True):
            scene = self.scenes[int(obs["scene_index"][e])]
            target = self._target(scene, pose[e, n, :2], goal[e, n])
            actions[e, n] = self.steer(pose[e, n], target)
        return actions, None

    def _target(self, scene: Scene, position: np.ndarray, goal: np.ndarray) -> np.ndarray:
        path = scene.shortest_path(position, goal)
        ahead = np.linalg.norm(path - position, axis=1) <= self.lookahead
        for k in np.flatnonzero(ahead)[::-1]:
            if _in_view(scene, position, path[k]):
                return path[k]
        return path[min(1, len(path) - 1)]

    def steer(self, pose: np.ndarray, target: np.ndarray) -> np.ndarray:
        """Action turning towards ``target`` and driving as far as is safe, ``(2,)``."""
        p = self.params
        delta = target - pose[:2]
        error = float(wrap_angle(np.arctan2(delta[1], delta[0]) - pose[2]))
        turn = np.clip(error / (p.max_angular * p.step_seconds), -1.0, 1.0)
        # Drive only when roughly facing the target; never overshoot it.
        facing = max(0.0, float(np.cos(error))) ** 2
        speed = min(1.0, float(np.linalg.norm(delta)) / (p.max_linear * p.step_seconds))
        return np.array([speed * facing, turn])


def _in_view(scene: Scene, a: np.ndarray, b: np.ndarray) -> bool:
    """The straight segment a→b stays on navigable cells (sampled every 5 cm)."""
    k = max(2, int(np.linalg.norm(b - a) / 0.05) + 1)
    points = a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)
    return bool(scene.nav.is_navigable(points).all())
