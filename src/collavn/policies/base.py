"""The interface every policy follows, and the random baseline.

A policy acts for a batch of agents::

    state = policy.initial_state(num_envs, num_agents)
    actions, state = policy.act(obs, state)      # actions: (E, N, 2) in [-1, 1]

``obs`` is the vector env's observation dict (arrays ``(E, N, ...)``); an agent whose
``obs["step"]`` is 0 has just started an episode (reset any memory for it). A policy
that samples draws from :class:`EpisodeRandom`: one generator per episode, seeded from
the policy's seed and ``obs["episode_seed"]``, so its actions in an episode do not
depend on how many envs run beside it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np


@dataclass
class CommStats:
    """Communication tallied over active agent-steps (all zero for a silent policy).

    Attributes:
        agent_steps: Active agent-steps seen.
        received: Of those, steps in which at least one teammate's value entered ω.
        when: Steps in which the agent's own gate opened (it communicated at all).
        bytes: Bytes the agents sent.
    """

    agent_steps: int = 0
    received: int = 0
    when: int = 0
    bytes: float = 0.0

    def add(self, other: CommStats) -> None:
        """Accumulate ``other`` into this tally."""
        self.agent_steps += other.agent_steps
        self.received += other.received
        self.when += other.when
        self.bytes += other.bytes

    def rates(self) -> dict[str, float]:
        """``received_rate``, ``when_rate`` and ``bytes_per_agent_step``."""
        n = max(self.agent_steps, 1)
        return {"received_rate": self.received / n, "when_rate": self.when / n,
                "bytes_per_agent_step": self.bytes / n}


class Policy(Protocol):
    """Anything with ``initial_state`` and ``act`` over ``(E, N)`` agents."""

    def initial_state(self, num_envs: int, num_agents: int) -> Any:
        """Recurrent state for a fresh batch (``None`` if memoryless)."""
        ...

    def act(self, obs: dict[str, np.ndarray], state: Any) -> tuple[np.ndarray, Any]:
        """``(E, N, 2)`` actions in ``[-1, 1]`` and the next state."""
        ...

    def communication(self) -> CommStats:
        """Communication so far (zeros for policies that do not talk)."""
        ...


class EpisodeRandom:
    """One random generator per env, restarted at every episode start.

    The generator of an episode is seeded with ``(seed, obs["episode_seed"][e])``.
    """

    def __init__(self, seed: int = 0) -> None:
        self.seed = seed
        self._rngs: list[np.random.Generator] = []
        self._seeds = np.zeros(0, np.int64)

    def generators(self, obs: dict[str, np.ndarray]) -> list[np.random.Generator]:
        """The ``E`` generators for this step (fresh ones where an episode starts)."""
        seeds = np.asarray(obs["episode_seed"], dtype=np.int64)
        starting = (np.asarray(obs["step"]) == 0).all(axis=1)
        if len(self._rngs) != len(seeds):
            self._rngs = [np.random.default_rng(0) for _ in seeds]
            self._seeds = np.full(len(seeds), -1, np.int64)
        for e in np.flatnonzero(starting | (seeds != self._seeds)):
            self._rngs[e] = np.random.default_rng([self.seed, int(seeds[e])])
        self._seeds = seeds.copy()
        return self._rngs

    def uniform(self, obs: dict[str, np.ndarray], low: float, high: float,
                shape: tuple[int, ...]) -> np.ndarray:
        """``(E, *shape)`` uniform draws, env ``e`` from its episode's generator."""
        return np.stack([g.uniform(low, high, shape) for g in self.generators(obs)])

    def normal(self, obs: dict[str, np.ndarray], shape: tuple[int, ...]) -> np.ndarray:
        """``(E, *shape)`` standard normal draws, env ``e`` from its episode's generator."""
        return np.stack([g.standard_normal(shape) for g in self.generators(obs)])


class RandomPolicy:
    """Uniform actions in ``[-1, 1]²``, drawn per episode (:class:`EpisodeRandom`)."""

    def __init__(self, seed: int = 0) -> None:
        self.random = EpisodeRandom(seed)

    def initial_state(self, num_envs: int, num_agents: int) -> None:
        """Memoryless."""
        return None

    def act(self, obs: dict[str, np.ndarray], state: None) -> tuple[np.ndarray, None]:
        """Uniform random actions."""
        n = obs["active"].shape[1]
        return self.random.uniform(obs, -1.0, 1.0, (n, 2)), None

    def communication(self) -> CommStats:
        """Random agents never talk."""
        return CommStats()
