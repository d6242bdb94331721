"""The shortest-path oracle: the privileged expert that imitation learns from."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from collavn.policies.base import CommStats
from collavn.scenes.navigation import GeodesicField
from collavn.scenes.scene import Scene
from collavn.simulation.kinematics import AgentParams, drive, wrap_angle


class OraclePolicy:
    """Follows the geodesic shortest path with the robot's own kinematics.

    Needs privileged observations (``EnvConfig(privileged=True)``): world poses, goal
    positions and the scene index. Each step it aims at the farthest point of the
    shortest path within ``lookahead`` metres that is in straight view, turning
    towards it and driving as far as the turn allows (pure pursuit). That action is
    first simulated with the real kinematics against the scene and the other agents
    of the env; if it would collide (an arc clipping a corner, a robot in the way),
    the oracle instead takes the collision-free action among a small grid whose end
    point is nearest the goal on a geodesic field in which the other robots' bodies
    are obstacles. It is the ceiling a learned agent can hope for on these kinematics.
    """

    def __init__(self, scenes: Sequence[Scene], params: AgentParams | None = None,
                 lookahead: float = 1.2) -> None:
        self.scenes = list(scenes)
        self.params = params or AgentParams()
        self.lookahead = lookahead
        v, w = np.meshgrid([1.0, 0.6, 0.3, 0.0], np.linspace(-1.0, 1.0, 9))
        self._grid = np.stack([v.ravel(), w.ravel()], axis=1)

    def initial_state(self, num_envs: int, num_agents: int) -> None:
        """Memoryless (paths are recomputed from the current pose)."""
        return None

    def communication(self) -> CommStats:
        """The oracle never talks."""
        return CommStats()

    def act(self, obs: dict[str, np.ndarray], state: None) -> tuple[np.ndarray, None]:
        """Steer every active agent along its shortest path, around obstacles."""
        if "world_pose" not in obs:
            raise KeyError("the oracle needs privileged observations: "
                           "EnvConfig(privileged=True)")
        pose, goal, active = obs["world_pose"], obs["goal_position"], obs["active"]
        actions = np.zeros((*active.shape, 2))
        for e, n in zip(*np.nonzero(active), strict=True):
            scene = self.scenes[int(obs["scene_index"][e])]
            actions[e, n] = self.act_one(scene, pose[e], n, goal[e, n])
        return actions, None

    def act_one(self, scene: Scene, poses: np.ndarray, n: int, goal: np.ndarray) -> np.ndarray:
        """Agent ``n``'s ``(2,)`` action among the env's ``(N, 3)`` world poses."""
        field = scene.geodesic_field(goal)
        pursuit = self.steer(poses[n], self._target(scene, field, poses[n, :2]))
        return self._safe(scene, poses, n, goal, pursuit)

    def _target(self, scene: Scene, field: GeodesicField, position: np.ndarray) -> np.ndarray:
        path = field.path_from(position)
        ahead = np.linalg.norm(path - position, axis=1) <= self.lookahead
        for k in np.flatnonzero(ahead[1:])[::-1] + 1:  # path[0] is the agent itself
            if in_view(scene, position, path[k]):
                return path[k]
        return path[min(1, len(path) - 1)]

    def _safe(self, scene: Scene, poses: np.ndarray, n: int, goal: np.ndarray,
              preferred: np.ndarray) -> np.ndarray:
        """``preferred`` if it drives without contact, else a detour or the best grid action."""
        _, hit = self._simulate(scene, poses, n, preferred[None])
        if not hit[0]:
            return preferred
        # Plan around the other robots: their bodies become obstacles for this field.
        others = np.delete(poses[:, :2], n, axis=0)
        blocked = scene.nav.discs(others, 2 * self.params.radius)
        field = scene.nav.geodesic_field(goal, blocked=blocked)
        candidates = self._grid
        if np.isfinite(field.distance(poses[n, :2])):
            detour = self.steer(poses[n], self._target(scene, field, poses[n, :2]))
            candidates = np.concatenate([detour[None], self._grid])
        end, hit = self._simulate(scene, poses, n, candidates)
        score = field.distance(end)
        score = np.where(hit | ~np.isfinite(score), 1e6 + score, score)
        if len(candidates) > len(self._grid) and not hit[0]:
            return candidates[0]
        score[np.isnan(score)] = np.inf
        return candidates[int(np.argmin(score))]

    def _simulate(self, scene: Scene, poses: np.ndarray, n: int,
                  candidates: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """End positions ``(K, 2)`` and contact flags ``(K,)`` of agent ``n`` per action.

        Each candidate runs in its own copy of the env; the other agents stand still.
        """
        k, agents = len(candidates), len(poses)
        moving = np.zeros((k, agents), dtype=bool)
        moving[:, n] = True
        action = np.zeros((k, agents, 2))
        action[:, n] = candidates
        out = drive(scene.nav, np.broadcast_to(poses[:, :2], (k, agents, 2)),
                    np.broadcast_to(poses[:, 2], (k, agents)), action, moving, self.params)
        return out.position[:, n], out.collided[:, n]

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


def in_view(scene: Scene, a: np.ndarray, b: np.ndarray) -> bool:
    """The straight segment a→b stays on navigable cells (sampled every 5 cm)."""
    k = max(2, int(np.linalg.norm(b - a) / 0.05) + 1)
    points = a + np.linspace(0.0, 1.0, k)[:, None] * (b - a)
    return bool(scene.nav.is_navigable(points).all())


def in_sight(scene: Scene, position: np.ndarray, goal: np.ndarray, sight: float) -> bool:
    """The goal is *in sight*: within ``sight`` metres and the straight way there navigable.

    The seeker's switch from searching to homing, and the evaluation's ``sighted_step``.
    """
    return bool(np.linalg.norm(goal - position) <= sight and in_view(scene, position, goal))


def track_sighting(seen: np.ndarray, obs: dict[str, np.ndarray], scenes: Sequence[Scene],
                   sight: float) -> np.ndarray:
    """``(E, N)`` bool: the goal has been :func:`in_sight` this episode (a latch).

    ``seen`` is the flag before this step; a new episode (``obs["step"] == 0``) clears it
    and an agent that no longer runs keeps its own. Reads the privileged observations
    (``EnvConfig(privileged=True)``); returns a new array.
    """
    seen = seen & (obs["step"] > 0)
    pose, goal = obs["world_pose"], obs["goal_position"]
    for e, n in zip(*np.nonzero(obs["active"] & ~seen), strict=True):
        scene = scenes[int(obs["scene_index"][e])]
        seen[e, n] = in_sight(scene, pose[e, n, :2], goal[e, n], sight)
    return seen
