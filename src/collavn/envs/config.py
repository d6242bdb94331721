"""Configuration of the environments and where their episodes come from."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Annotated, Literal

import numpy as np
import tyro

from collavn.configs import check_count, check_number
from collavn.datasets.episode import DIFFICULTY_BINS, Episode
from collavn.errors import CollavnError, ConfigError
from collavn.scenes.scene import Scene
from collavn.tasks import TASKS, TaskName, TaskSpec

#: Difficulty of on-the-fly episodes: a bin, or ``mixed`` (a bin drawn per episode).
DifficultyChoice = Literal["easy", "medium", "hard", "mixed"]


@dataclass(frozen=True)
class EnvConfig:
    """What the agents sense and how episodes run.

    Attributes:
        task: ``commongoal``, ``specificgoal`` or ``adhocoop``.
        num_agents: Agents per environment (N).
        panorama_width: Panorama width in pixels (360°); paper 512.
        panorama_height: Panorama height (±45°); paper 128.
        goal_size: Goal image side (pinhole 90° FOV); paper 128.
        camera_height: Camera height above the floor in metres (paper: 0.9).
        depth: Also return the panorama's depth (metres).
        gt_map: Also return ground-truth egocentric occupancy/explored maps projected
            from the depth (for supervising a map module; never a policy input).
        gt_map_size: Side in cells of the ground-truth map (10 cm cells).
        free_space: Directions of the free-space sensor (0 = off): per direction, every
            ``W/free_space``-th panorama column from straight behind, the metres the
            robot's body can drive straight before touching what the depth panorama
            shows, up to 4 m (``free_space (E, N, D)``; see :mod:`collavn.envs.free_space`).
            Renders nothing extra: it is read off the depth the renderer makes anyway.
        explore_action: Also return ``explore_action (E, N, 2)``: the move the goal-blind
            explorer's rule makes now (drive straight while free, else turn in place to
            the most open direction; away from straight ahead when the last drive fell
            short of what its action should have driven), a function of the agent's own
            depth panorama, odometry and last action only (see
            :class:`~collavn.envs.free_space.ExploreRule`; the ``seeker``'s search move).
        odometry_noise: Std of Gaussian noise added to ``pose_delta`` (metres and
            radians); 0 = noise-free (default).
        max_steps: Episode length T.
        success_reward: Reward added on the step an agent reaches its goal; 0 (default)
            is the paper's reward, geodesic progress minus collisions, which pays
            nothing for the last metre that turns "near" into success.
        collision_penalty: Subtracted from an agent's reward on every step it collides
            (with the scene or a teammate); 0.05 (default) is the paper's.
        difficulty: Difficulty of episodes sampled on the fly (``easy``, ``medium``,
            ``hard`` or ``mixed``); unused when episodes come from a dataset.
        backend: Renderer backend: ``embree`` (CPU) or ``warp`` (CUDA or CPU).
        device: Renderer device for the ``warp`` backend (``cpu``, ``cuda:0``).
        render_threads: CPU threads for the ``embree`` backend.
        obs_device: ``None`` for NumPy observations, or a torch device (``"cpu"``,
            ``"cuda:0"``) to receive every observation as a torch tensor there.
        privileged: Also return ``world_pose (E, N, 3)``, ``goal_position (E, N, 2)``
            and ``scene_index (E,)`` — for experts (the oracle, imitation targets) and
            tools, never for a learning agent's policy.
    """

    task: Annotated[TaskName, tyro.conf.arg(aliases=("--task",))] = "commongoal"
    num_agents: Annotated[int, tyro.conf.arg(aliases=("--agents",))] = 2
    panorama_width: Annotated[int, tyro.conf.arg(aliases=("--panorama-width",))] = 512
    panorama_height: Annotated[int, tyro.conf.arg(aliases=("--panorama-height",))] = 128
    goal_size: Annotated[int, tyro.conf.arg(aliases=("--goal-size",))] = 128
    camera_height: float = 0.9
    depth: bool = False
    gt_map: bool = False
    gt_map_size: int = 64
    free_space: int = 0
    explore_action: bool = False
    odometry_noise: float = 0.0
    max_steps: int = TaskSpec.max_steps
    success_reward: float = TaskSpec.success_reward
    collision_penalty: float = TaskSpec.collision_penalty
    difficulty: DifficultyChoice = "mixed"
    backend: Literal["embree", "warp"] = "embree"
    device: str = "cpu"
    render_threads: Annotated[int, tyro.conf.arg(aliases=("--render-threads",))] = 2
    obs_device: str | None = None
    privileged: bool = False

    def __post_init__(self) -> None:
        check_count("--agents", self.num_agents)
        for name in ("panorama_width", "panorama_height", "goal_size"):
            check_count(f"--{name.replace('_', '-')}", getattr(self, name))
        check_count("--env.max-steps", self.max_steps)
        check_count("--env.gt-map-size", self.gt_map_size)
        check_count("--env.free-space", self.free_space, 0)
        if self.free_space and self.panorama_width % self.free_space:
            raise ConfigError(f"--env.free-space {self.free_space} must divide the panorama "
                              f"width {self.panorama_width}")
        check_count("--render-threads", self.render_threads)
        check_number("--env.camera-height", self.camera_height)
        check_number("--env.odometry-noise", self.odometry_noise, allow_minimum=True)
        check_number("--env.success-reward", self.success_reward, allow_minimum=True)
        check_number("--env.collision-penalty", self.collision_penalty, allow_minimum=True)
        if self.difficulty not in (*DIFFICULTY_BINS, "mixed"):
            raise ConfigError(f"unknown difficulty {self.difficulty!r}; expected one of "
                              f"{', '.join(DIFFICULTY_BINS)} or mixed")
        if self.task not in TASKS:
            raise ConfigError(f"unknown task {self.task!r}; expected one of "
                              f"{', '.join(TASKS)}")


class EpisodeSource:
    """Episodes for one scene: a fixed list (in order, cycling) or sampled on the fly."""

    def __init__(self, scene: Scene, config: EnvConfig,
                 episodes: Sequence[Episode] | None = None) -> None:
        self.scene, self.config = scene, config
        self.episodes = list(episodes) if episodes is not None else None
        self._next = 0
        self._forced: list[Episode] = []
        if self.episodes is not None:
            if not self.episodes:
                raise CollavnError(f"no episodes given for scene {scene.name}")
            for ep in self.episodes:
                if ep.scene.content_hash != scene.content_hash:
                    raise CollavnError(
                        f"episode {ep.episode_id} was made for scene {ep.scene.name} "
                        f"({ep.scene.content_hash[:12]}), not {scene.name} "
                        f"({scene.content_hash[:12]})")
                if ep.num_agents != config.num_agents:
                    raise CollavnError(f"episode {ep.episode_id} has {ep.num_agents} "
                                       f"agents, the env has {config.num_agents}")

    def push(self, episode: Episode) -> None:
        """Make ``episode`` the next one returned (e.g. ``reset(options=...)``)."""
        if episode.scene.content_hash != self.scene.content_hash:
            raise CollavnError(f"episode {episode.episode_id} was made for scene "
                               f"{episode.scene.name}, not {self.scene.name}")
        self._forced.append(episode)

    def next(self, rng: np.random.Generator) -> Episode:
        """The next episode: a pushed one, else dataset order, else a fresh sample."""
        if self._forced:
            return self._forced.pop(0)
        if self.episodes is not None:
            ep = self.episodes[self._next % len(self.episodes)]
            self._next += 1
            return ep
        from collavn.datasets.generator import sample_episodes

        difficulty: str = self.config.difficulty
        if difficulty == "mixed":
            difficulty = str(rng.choice(list(DIFFICULTY_BINS)))
        task = "commongoal" if self.config.task == "adhocoop" else self.config.task
        return sample_episodes(self.scene, task, self.config.num_agents, difficulty, 1,
                               rng)[0]
