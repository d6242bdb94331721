"""The PettingZoo ``ParallelEnv`` front door: one scene, agents named ``agent_0…``.

Each agent observes a dict: ``panorama`` (3, H, W) uint8, ``goal`` (3, G, G) uint8,
``pose_delta`` (3,) float32 odometry since its previous step in its previous frame
(x forward, y left, yaw CCW), ``pose`` (3,) float32 its pose in its own start frame,
and optionally ``depth`` (H, W) float32, ``gt_map`` (2, M, M) float32, ``free_space``
(D,) float32 metres (``EnvConfig.free_space``) and ``explore_action`` (2,) float32
(``EnvConfig.explore_action``). Actions are
Box(-1, 1, (2,)): normalised (linear, angular) velocity; out-of-range values are
clipped, NaN/inf raise :class:`~collavn.errors.ActionError` naming the agent.

An agent leaves ``agents`` on the step it terminates (reached its goal) or is
truncated (hit ``max_steps``); the episode is over when ``agents`` is empty.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from collavn.datasets.episode import Episode
from collavn.envs.config import EnvConfig
from collavn.envs.free_space import FREE_SPACE_RANGE
from collavn.envs.vector import VectorEnv
from collavn.errors import ActionError
from collavn.scenes.scene import Scene


class CollaVNParallelEnv(ParallelEnv):
    """Multi-agent visual navigation in one scene (PettingZoo Parallel API)."""

    metadata: ClassVar[dict[str, Any]] = {"name": "collavn_v0", "render_modes": ["rgb_array"],
                                          "is_parallelizable": True}

    def __init__(self, scene: Scene, config: EnvConfig | None = None,
                 episodes: Sequence[Episode] | None = None,
                 render_mode: str | None = "rgb_array") -> None:
        self.config = config or EnvConfig()
        self.scene = scene
        self.render_mode = render_mode
        self.possible_agents = [f"agent_{i}" for i in range(self.config.num_agents)]
        self.agents: list[str] = []
        self._vec = VectorEnv([scene], 1, self.config,
                              episodes=None if episodes is None else [episodes],
                              autoreset=False)
        cfg = self.config
        h, w, g = cfg.panorama_height, cfg.panorama_width, cfg.goal_size
        fields: dict[str, spaces.Space[Any]] = {
            "panorama": spaces.Box(0, 255, (3, h, w), np.uint8),
            "goal": spaces.Box(0, 255, (3, g, g), np.uint8),
            "pose_delta": spaces.Box(-np.inf, np.inf, (3,), np.float32),
            "pose": spaces.Box(-np.inf, np.inf, (3,), np.float32),
        }
        if cfg.depth:
            fields["depth"] = spaces.Box(0.0, np.inf, (h, w), np.float32)
        if cfg.gt_map:
            fields["gt_map"] = spaces.Box(0.0, 1.0, (2, cfg.gt_map_size, cfg.gt_map_size),
                                          np.float32)
        if cfg.free_space:
            fields["free_space"] = spaces.Box(0.0, FREE_SPACE_RANGE, (cfg.free_space,),
                                              np.float32)
        if cfg.explore_action:
            fields["explore_action"] = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._obs_space = spaces.Dict(fields)
        self._act_space = spaces.Box(-1.0, 1.0, (2,), np.float32)
        self._last: dict[str, np.ndarray] | None = None

    def observation_space(self, agent: str) -> spaces.Space[Any]:
        """The same Dict space for every agent."""
        return self._obs_space

    def action_space(self, agent: str) -> spaces.Space[Any]:
        """Box(-1, 1, (2,)): (linear, angular) velocity."""
        return self._act_space

    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, Any], dict[str, Any]]:
        """Start an episode: ``options={"episode": Episode}`` forces a given one."""
        if options and "episode" in options:
            self._vec.groups[0].source.push(options["episode"])
        obs, _ = self._vec.reset(seed=seed)
        self._last = obs
        self.agents = list(self.possible_agents)
        return self._split(obs, self.agents), {a: {} for a in self.agents}

    def step(self, actions: dict[str, Any]) -> tuple[dict[str, Any], dict[str, float],
                                                     dict[str, bool], dict[str, bool],
                                                     dict[str, Any]]:
        """Step every live agent; each must have an action."""
        if not self.agents:
            raise ActionError("the episode is over: call reset()")
        batch = np.zeros((1, self.config.num_agents, 2))
        for i, name in enumerate(self.possible_agents):
            if name in self.agents:
                if name not in actions:
                    raise ActionError(f"no action given for live agent {name}")
                a = np.asarray(actions[name], dtype=np.float64)
                if a.shape != (2,):
                    raise ActionError(f"action of {name} must have shape (2,), got {a.shape}")
                batch[0, i] = a  # NaN/inf: refused by check_actions, naming agent_i
        obs, reward, term, trunc, info = self._vec.step(batch)
        self._last = obs
        live = list(self.agents)
        idx = {a: self.possible_agents.index(a) for a in live}
        world = self._vec.groups[0].world
        infos = {a: {"collided": bool(info["collided"][0, i]),
                     "success": bool(world.success[0, i]),
                     "geodesic_distance": float(world.distance[0, i])}
                 for a, i in idx.items()}
        result = (self._split(obs, live), {a: float(reward[0, i]) for a, i in idx.items()},
                  {a: bool(term[0, i]) for a, i in idx.items()},
                  {a: bool(trunc[0, i]) for a, i in idx.items()}, infos)
        self.agents = [a for a in live if not (term[0, idx[a]] or trunc[0, idx[a]])]
        return result

    def render(self) -> np.ndarray | None:
        """An ``(H, W, 3)`` uint8 picture: each agent's panorama beside its goal image."""
        if self.render_mode is None or self._last is None:
            return None
        from collavn.rendering.frames import views_strip

        return views_strip(self._last["panorama"][0], self._last["goal"][0])

    def state(self) -> np.ndarray:
        """Global state for centralised tools: ``(N, 3)`` world poses (not an observation)."""
        return self._vec.groups[0].world.poses()[0].astype(np.float32)

    def _split(self, obs: dict[str, np.ndarray], agents: list[str]) -> dict[str, Any]:
        keys = [k for k in self._obs_space.spaces]
        return {a: {k: obs[k][0, self.possible_agents.index(a)] for k in keys} for a in agents}


def make_parallel_env(scene: Scene | str, config: EnvConfig | None = None,
                      episodes: Sequence[Episode] | None = None, **overrides: Any
                      ) -> CollaVNParallelEnv:
    """Build a PettingZoo env; ``scene`` may be a spec like ``procedural:0``.

    Keyword ``overrides`` replace fields of ``config`` (e.g. ``num_agents=3``).
    """
    from dataclasses import replace

    if isinstance(scene, str):
        from collavn.scenes.loading import load_scene

        scene = load_scene(scene)
    config = replace(config or EnvConfig(), **overrides)
    return CollaVNParallelEnv(scene, config, episodes)
