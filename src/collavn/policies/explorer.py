"""The goal-blind explorer: drive straight at full speed, turn away when blocked.

It never looks at the goal image. From its own depth panorama alone (no map, no
privileged pose) it finds the obstacle points around it, measures how far it could
drive straight in every panorama direction before its body would touch one, and:

- if the way ahead is clear, drives straight ahead — at full speed, or just short of
  the obstacle when that is nearer than one step's travel;
- if blocked — or if its odometry says the last drive fell short (something below
  the camera's view, or the navigation grid's 10 cm cells, stopped it) — turns in
  place towards an open direction: one whose free run is
  close to the longest (within ``open_fraction`` of it), avoiding the half-turn back
  when any other is open. Among those it chooses at random, from a generator
  private to the agent and the episode, so ties are broken without bias.

Driving and turning are never mixed, so the robot only moves along straight segments
it has seen to be free; it collides only with what its panorama cannot see (a
teammate stepping in, or an obstacle between two rays of a coarse panorama).

**It is the bar a goal-using agent must clear.** Because easy goals are 1.5–3 m away
and success needs only passing within 1 m, covering ground quickly already succeeds
often: a previous measurement found such an explorer at ~0.62 SR on easy val
episodes (CommonGoal, N = 2) against random's ~0.40; this one scores 0.590 against
random's 0.375 on 200 easy val episodes (CommonGoal, N = 2, 128×32 panoramas; paired
difference +0.215, 95 % interval [+0.152, +0.275], ``collavn compare``). A learned
agent that does not beat it has not shown that it uses the goal. (Its DTS is worse
than random's: when it misses, it has driven far away.)

Determinism: each agent's generator is seeded at the start of its episode
(``obs["step"] == 0``) from the policy seed, the agent's index and the bytes of its
first panorama, so an episode plays the same whatever the batch size or order, and
agents and episodes do not share random draws. Needs ``EnvConfig(depth=True)``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass

import numpy as np

from collavn.envs.free_space import (
    ExploreRule,
    bumped,
    expected_drive,
    free_runs,
    panorama_azimuths,
)
from collavn.policies.base import CommStats
from collavn.simulation.kinematics import AgentParams

__all__ = ["ExplorerPolicy", "ExplorerState", "free_runs", "panorama_azimuths"]


class ExplorerPolicy:
    """Straight ahead until blocked, then turn to an open direction (seeded ties).

    Args:
        seed: Seeds every agent's per-episode generator.
        params: The robot (radius, speeds, step length).
        margin: Extra clearance kept from obstacle points, metres (covers the 10 cm
            navigation grid and the gaps between rays).
        min_advance: Drive only if at least this many metres are free ahead.
        open_fraction: A direction is open if its free run is at least this
            fraction of the longest one.
        camera_height: Camera height above the floor (``EnvConfig.camera_height``).
        fov_deg: The panorama's vertical field of view.
        band: Heights above the floor between which a hit is an obstacle (the
            navigation grid's ``step_height`` and ``agent_height``): lower is floor
            or a rug, higher (ceilings, lintels) passes over the robot.
        deterministic: Take the open direction nearest the heading instead of a random
            one (no generator is drawn from): the move of the ``explore_action`` sensor
            (:meth:`~collavn.envs.free_space.ExploreRule.moves`).
    """

    def __init__(self, seed: int = 0, params: AgentParams | None = None, margin: float = 0.12,
                 min_advance: float = 0.25, open_fraction: float = 0.8,
                 camera_height: float = 0.9, fov_deg: float = 90.0,
                 band: tuple[float, float] = (0.05, 1.0), deterministic: bool = False) -> None:
        self.seed = seed
        self.params = params or AgentParams()
        self.rule = ExploreRule(margin, min_advance, open_fraction, band)
        self.camera_height, self.fov = camera_height, np.deg2rad(fov_deg)
        self.deterministic = deterministic

    def initial_state(self, num_envs: int, num_agents: int) -> ExplorerState:
        """Fresh generators (re-seeded when each agent's episode starts), no drive yet."""
        rngs = [[np.random.default_rng([self.seed, n]) for n in range(num_agents)]
                for _ in range(num_envs)]
        return ExplorerState(rngs, np.zeros((num_envs, num_agents)))

    def communication(self) -> CommStats:
        """The explorer never talks."""
        return CommStats()

    def act(self, obs: dict[str, np.ndarray], state: ExplorerState
            ) -> tuple[np.ndarray, ExplorerState]:
        """``(E, N, 2)`` actions: full speed ahead, or a turn in place when blocked."""
        if "depth" not in obs:
            raise KeyError("the explorer needs depth observations: EnvConfig(depth=True)")
        depth, active, step = obs["depth"], obs["active"], obs["step"]
        moved = np.linalg.norm(np.asarray(obs["pose_delta"])[..., :2], axis=-1)
        bump = bumped(moved, state.expected) & (step > 0)
        actions = np.zeros((*active.shape, 2))
        agents = list(zip(*np.nonzero(active), strict=True))
        if agents:
            for e, n in agents:
                if step[e, n] == 0:
                    state.rngs[e][n] = self._episode_rng(n, obs["panorama"][e, n])
            free = self.rule.free(depth[active], self.params, self.camera_height, self.fov)
            rngs = None if self.deterministic else [state.rngs[e][n] for e, n in agents]
            actions[active] = self.rule.moves(free, bump[active], self.params, rngs)
        self.executed(state, actions, active)
        return actions, state

    def executed(self, state: ExplorerState, actions: np.ndarray, active: np.ndarray) -> None:
        """Record the ``(E, N, 2)`` actions the env was given (the odometry check's base).

        The next step compares the distance driven with what they should have driven.
        """
        state.expected = expected_drive(actions, active, self.params)

    @property
    def radius(self) -> float:
        """Body radius plus the safety margin, metres."""
        return self.params.radius + self.rule.margin

    def _episode_rng(self, agent: int, panorama: np.ndarray) -> np.random.Generator:
        return np.random.default_rng([self.seed, agent,
                                      zlib.crc32(np.ascontiguousarray(panorama).tobytes())])


@dataclass
class ExplorerState:
    """Per-agent memory of the explorer.

    Attributes:
        rngs: ``[E][N]`` generators, re-seeded at each agent's episode start.
        expected: ``(E, N)`` metres the last action should have driven (0 for a turn).
    """

    rngs: list[list[np.random.Generator]]
    expected: np.ndarray
