"""A batched vector environment for training: ``E`` envs × ``N`` agents, arrays inside.

Environments may live in different scenes (env ``i`` uses ``scenes[i % len(scenes)]``);
all agents of all envs of one scene are rendered in one batched call.

Contract (Gymnasium vocabulary):

- ``step(actions (E, N, 2))`` returns ``(obs, reward (E, N), terminated (E, N),
  truncated (E, N), info)``. ``terminated`` is True on the step an agent reached its
  goal, ``truncated`` on the step it hit ``max_steps`` without succeeding; an agent
  that finished stays in place (still an obstacle), gets reward 0 and
  ``obs["active"] = False`` until its episode ends.
- An env's episode ends when all its agents have finished. **Autoreset mode:
  ``AutoresetMode.SAME_STEP``** — the env is reset within the same ``step`` call:
  the observation returned for it is the first of the new episode, and
  ``info["episode_records"]`` carries the finished episode's per-agent records
  (:class:`~collavn.metrics.AgentRecord`). ``info["episode_done"] (E,)`` marks those envs
  and ``info["final_poses"] (E, N, 3)`` holds every agent's world pose after the
  action, before any reset.
  The finished episode's last observation is not returned; a learner that
  bootstraps truncated agents should use the value of the previous observation.
- ``obs["episode_seed"] (E,)`` int64 seeds everything random *within* an episode:
  derived from the env's seed and the episode's id (fixed episodes) or its start
  count (sampled ones). The env draws odometry noise from it and sampling policies
  (random, stochastic checkpoints) draw their actions from it, so an episode's
  outcome depends on the seed and the episode only — never on ``num_envs`` or on
  which env slot ran it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from collavn.datasets.episode import Episode
from collavn.envs.config import EnvConfig, EpisodeSource
from collavn.envs.free_space import bumped, expected_drive
from collavn.envs.sensors import Sensors
from collavn.errors import CollavnError
from collavn.metrics import AgentRecord
from collavn.scenes.scene import Scene
from collavn.simulation.kinematics import AgentParams
from collavn.simulation.world import World, check_actions, relative_pose
from collavn.tasks import get_task, step_world

AUTORESET_MODE = "SAME_STEP"


@dataclass
class SceneGroup:
    """The envs of a :class:`VectorEnv` that live in one scene, stepped as one batch.

    Attributes:
        envs: ``(E_g,)`` global indices of the group's envs (local env ``i`` is global
            ``envs[i]``).
        world: Their simulator state.
        sensors: Their renderer and sensor models.
        source: Where their episodes come from.
        episodes: The episode running in each local env.
    """

    envs: np.ndarray
    world: World
    sensors: Sensors
    source: EpisodeSource
    episodes: list[Episode | None] = field(default_factory=list)


class VectorEnv:
    """``E`` environments stepped together; see the module docstring for the contract.

    Args:
        scenes: One or more scenes; env ``i`` lives in ``scenes[i % len(scenes)]``.
        num_envs: ``E``.
        config: Sensors, task and episode settings.
        episodes: Optional fixed episodes per scene (same order as ``scenes``); by
            default episodes are sampled on the fly from the env's random generator.
        params: Robot and timing.
        seed: Seeds the generator (episode sampling, odometry noise).
        autoreset: Reset finished envs within ``step`` (``SAME_STEP``). With False a
            finished env keeps its final state until :meth:`reset` (the PettingZoo
            wrapper uses this).
    """

    def __init__(self, scenes: Sequence[Scene], num_envs: int, config: EnvConfig,
                 episodes: Sequence[Sequence[Episode]] | None = None,
                 params: AgentParams | None = None, seed: int | None = None,
                 autoreset: bool = True) -> None:
        if not scenes:
            raise CollavnError("VectorEnv needs at least one scene")
        if num_envs < 1:
            raise CollavnError(f"num_envs must be ≥ 1, got {num_envs}")
        if episodes is not None and len(episodes) != len(scenes):
            raise CollavnError("give one episode list per scene")
        self.config, self.num_envs, self.num_agents = config, num_envs, config.num_agents
        self.autoreset = autoreset
        self.task = replace(get_task(config.task), max_steps=config.max_steps,
                            success_reward=config.success_reward,
                            collision_penalty=config.collision_penalty)
        self.params = params or AgentParams()
        self.rng = np.random.default_rng(seed)
        self._base_seed = int(self.rng.integers(2**62)) if seed is None else seed
        self._started = 0
        self._episode_seeds = np.zeros(num_envs, np.int64)
        self._noise = [np.random.default_rng(0) for _ in range(num_envs)]
        self.groups: list[SceneGroup] = []
        env_scene = np.arange(num_envs) % len(scenes)
        for s, scene in enumerate(scenes):
            envs = np.flatnonzero(env_scene == s)
            if len(envs) == 0:
                continue
            world = World(scene, len(envs), config.num_agents, self.params)
            source = EpisodeSource(scene, config, None if episodes is None else episodes[s])
            self.groups.append(SceneGroup(envs, world, Sensors(scene, config), source,
                                          [None] * len(envs)))
        self._goal_images = np.zeros((num_envs, config.num_agents, 3, config.goal_size,
                                      config.goal_size), dtype=np.uint8)
        self._last_pose = np.zeros((num_envs, config.num_agents, 3))
        self._expected = np.zeros((num_envs, config.num_agents))  # metres the last action

    # ---------------------------------------------------------------- public
    def reset(self, seed: int | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start a new episode in every env; returns ``(obs, info)``."""
        if seed is not None:
            self.rng = np.random.default_rng(seed)
            self._base_seed, self._started = seed, 0
        for group in self.groups:
            self._start(group, np.arange(group.world.num_envs))
        return self._deliver(self._observe()), {"episode_done": np.zeros(self.num_envs, bool)}

    def step(self, actions: np.ndarray) -> tuple[dict[str, Any], np.ndarray, np.ndarray,
                                                 np.ndarray, dict[str, Any]]:
        """Apply ``(E, N, 2)`` actions (a torch tensor too with ``obs_device``)."""
        if self.config.obs_device is not None:
            import torch

            actions = torch.as_tensor(actions).detach().cpu().numpy()
        actions = check_actions(actions, self.num_envs, self.num_agents)
        e, n = self.num_envs, self.num_agents
        reward, terminated = np.zeros((e, n), np.float32), np.zeros((e, n), bool)
        truncated, collided = np.zeros((e, n), bool), np.zeros((e, n), bool)
        done = np.zeros(e, dtype=bool)
        final_poses = np.zeros((e, n, 3))
        records: list[AgentRecord] = []
        for group in self.groups:
            envs, world = group.envs, group.world
            self._expected[envs] = expected_drive(actions[envs], world.running, self.params)
            out = step_world(world, actions[envs], self.task)
            final_poses[envs] = world.poses()
            reward[envs], terminated[envs] = out.reward, out.terminated
            truncated[envs], collided[envs] = out.truncated, out.collided
            finished = np.flatnonzero(~world.running.any(axis=1) & out.any_finished)
            if len(finished):
                done[envs[finished]] = True
                records += episode_records(group, finished)
                if self.autoreset:
                    self._start(group, finished)
        info = {"collided": collided, "episode_done": done, "episode_records": records,
                "final_poses": final_poses}
        return self._deliver(self._observe()), reward, terminated, truncated, info

    @property
    def scenes(self) -> list[Scene]:
        """The scene of each group, indexed by ``obs["scene_index"]``."""
        return [group.world.scene for group in self.groups]

    # -------------------------------------------------------------- internals
    def _start(self, group: SceneGroup, local: np.ndarray) -> None:
        world, envs = group.world, group.envs
        episodes = [group.source.next(self.rng) for _ in local]
        world.reset_envs(list(local), episodes)
        for e, ep in zip(local, episodes, strict=True):
            group.episodes[e] = ep
            key = ep.episode_id if group.source.episodes is not None else (
                f"{ep.episode_id}#{self._started}")
            self._started += 1
            seed = episode_seed(self._base_seed, key)
            self._episode_seeds[envs[e]] = seed
            self._noise[envs[e]] = np.random.default_rng([seed, 0])
        goal_poses = np.concatenate([world.goal[local], world.goal_yaw[local][..., None]], -1)
        self._goal_images[envs[local]] = group.sensors.goal_images(goal_poses)
        self._last_pose[envs[local]] = world.poses()[local]
        self._expected[envs[local]] = 0.0

    def _deliver(self, obs: dict[str, np.ndarray]) -> dict[str, Any]:
        """NumPy arrays, or torch tensors on ``config.obs_device``."""
        if self.config.obs_device is None:
            return obs
        import torch

        device = torch.device(self.config.obs_device)
        return {k: torch.from_numpy(v).to(device) for k, v in obs.items()}

    def _observe(self) -> dict[str, np.ndarray]:
        e, n, cfg = self.num_envs, self.num_agents, self.config
        obs: dict[str, np.ndarray] = {
            "panorama": np.zeros((e, n, 3, cfg.panorama_height, cfg.panorama_width), np.uint8),
            "goal": self._goal_images.copy(),
            "pose_delta": np.zeros((e, n, 3), np.float32),
            "pose": np.zeros((e, n, 3), np.float32),
            "active": np.zeros((e, n), bool),
            "step": np.zeros((e, n), np.int64),
            "episode_seed": self._episode_seeds.copy(),
        }
        if cfg.depth or cfg.gt_map:
            obs["depth"] = np.zeros((e, n, cfg.panorama_height, cfg.panorama_width), np.float32)
        if cfg.gt_map:
            obs["gt_map"] = np.zeros((e, n, 2, cfg.gt_map_size, cfg.gt_map_size), np.float32)
        if cfg.free_space:
            obs["free_space"] = np.zeros((e, n, cfg.free_space), np.float32)
        if cfg.explore_action:
            obs["explore_action"] = np.zeros((e, n, 2), np.float32)
        if cfg.privileged:
            obs["world_pose"] = np.zeros((e, n, 3), np.float64)
            obs["goal_position"] = np.zeros((e, n, 2), np.float64)
            obs["scene_index"] = np.zeros(e, np.int64)
        for g, group in enumerate(self.groups):
            envs, world, sensors = group.envs, group.world, group.sensors
            poses = world.poses()
            views = sensors.panoramas(poses)
            obs["panorama"][envs] = views.rgb
            if "depth" in obs:
                obs["depth"][envs] = views.depth
            if cfg.gt_map:
                obs["gt_map"][envs] = sensors.gt_maps(poses, views.depth)
            if cfg.free_space:
                obs["free_space"][envs] = sensors.free_space(views.depth, world.params.radius)
            delta = relative_pose(self._last_pose[envs], poses)
            if cfg.odometry_noise > 0:
                delta = delta + np.stack([self._noise[i].normal(0.0, cfg.odometry_noise,
                                                                delta.shape[1:])
                                          for i in envs])
            obs["pose_delta"][envs] = delta
            if cfg.explore_action:
                bump = bumped(np.linalg.norm(delta[..., :2], axis=-1), self._expected[envs])
                obs["explore_action"][envs] = sensors.explore_action(views.depth, bump,
                                                                     world.params)
            obs["pose"][envs] = world.relative_to_start()
            obs["active"][envs] = world.running
            obs["step"][envs] = world.steps
            if cfg.privileged:
                obs["world_pose"][envs], obs["goal_position"][envs] = poses, world.goal
                obs["scene_index"][envs] = g
            self._last_pose[envs] = poses
        return obs


def episode_seed(seed: int, key: str) -> int:
    """A seed in ``[0, 2^63)`` for the episode ``key`` of an env seeded with ``seed``."""
    digest = hashlib.sha256(f"{seed}:{key}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1


def episode_records(group: SceneGroup, local_envs: np.ndarray) -> list[AgentRecord]:
    """Per-agent records of the episodes in ``local_envs`` of ``group``."""
    out, world = [], group.world
    for e in local_envs:
        ep = group.episodes[e]
        assert ep is not None
        for a in range(world.num_agents):
            out.append(AgentRecord(
                episode_id=ep.episode_id, agent=a, difficulty=ep.difficulty,
                success=bool(world.success[e, a]), steps=int(world.steps[e, a]),
                path_length=float(world.path_length[e, a]),
                start_distance=float(world.start_distance[e, a]),
                final_distance=float(world.distance[e, a]),
                collisions=int(world.collisions[e, a])))
    return out
