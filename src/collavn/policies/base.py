"""The interface every policy follows, and the random baseline.

A policy acts for a batch of agents::

    state = policy.initial_state(num_envs, num_agents)
    actions, state = policy.act(obs, state)      # actions: (E, N, 2) in [-1, 1]

``obs`` is the vector env's observation dict (arrays ``(E, N, ...)``); an agent whose
``obs["step"]`` is 0 has just started an episode (reset any memory for it).
"""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np


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
