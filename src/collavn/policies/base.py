"""The interface every policy follows, and the random baseline.

A policy acts for a batch of agents::

    state = policy.initial_state(num_envs, num_agents)
    actions, state = policy.act(obs, state)      # actions: (E, N, 2) in [-1, 1]

``obs`` is the vector env's observation dict (arrays ``(E, N, ...)``); an agent whose
``obs["step"]`` is 0 has just started an episode (reset any memory for it).
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

    def communication(self) -> CommStats:
        """Random agents never talk."""
        return CommStats()
