"""The recurrent state of a batch of agents: GRU hidden states, map S_t, pose, memory.

A frozen dataclass of ``(E, N, ...)`` tensors; every operation returns a new state, so
a rollout can keep the state it started a sequence from (recurrent PPO). ``N`` is free:
the same model runs with any number of agents.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, fields

import torch
from torch import Tensor

from collavn.models.config import ModelConfig
from collavn.models.mapping import MAP_CHANNELS


@dataclass(frozen=True)
class AgentState:
    """Everything an agent carries from one step to the next.

    Attributes:
        actor_h: ``(E, N, hidden_size)`` actor GRU state.
        critic_h: ``(E, N, critic_hidden_size)`` critic GRU state.
        grid: ``(E, N, 4, S, S)`` map S_t (obstacle, explored, trajectory, location).
        features: ``(E, N, F, G, G)`` visual-feature grid of S_t.
        pose: ``(E, N, 3)`` (x, y, yaw) in the episode-start frame.
        mem_keys: ``(E, N, T, key_dim)`` communication memory (T = 0 without memory).
        mem_values: ``(E, N, T, value_dim)``.
        mem_count: ``(E, N)`` int64, entries written since the episode start.
        steps: ``(E, N)`` int64, steps taken since the episode start.
    """

    actor_h: Tensor
    critic_h: Tensor
    grid: Tensor
    features: Tensor
    pose: Tensor
    mem_keys: Tensor
    mem_values: Tensor
    mem_count: Tensor
    steps: Tensor

    @classmethod
    def zeros(cls, cfg: ModelConfig, num_envs: int, num_agents: int,
              device: torch.device | str | None = None,
              dtype: torch.dtype = torch.float32) -> AgentState:
        """The state at an episode start for ``num_envs × num_agents`` agents."""
        e, n, m, c = num_envs, num_agents, cfg.map, cfg.comm

        def z(*shape: int, kind: torch.dtype = dtype) -> Tensor:
            return torch.zeros(e, n, *shape, dtype=kind, device=device)

        slots = c.memory_slots if c.variant == "memory" else 0
        return cls(
            actor_h=z(cfg.hidden_size), critic_h=z(cfg.critic_hidden_size),
            grid=z(MAP_CHANNELS, m.size, m.size),
            features=z(m.feature_channels, m.feature_size, m.feature_size),
            pose=z(3), mem_keys=z(slots, c.key_dim), mem_values=z(slots, c.value_dim),
            mem_count=z(kind=torch.int64), steps=z(kind=torch.int64))

    @property
    def num_envs(self) -> int:
        """E."""
        return self.actor_h.shape[0]

    @property
    def num_agents(self) -> int:
        """N."""
        return self.actor_h.shape[1]

    def apply(self, fn: Callable[[Tensor], Tensor]) -> AgentState:
        """A new state with ``fn`` applied to every tensor."""
        return AgentState(**{f.name: fn(getattr(self, f.name)) for f in fields(self)})

    def where(self, mask: Tensor, other: AgentState) -> AgentState:
        """Take ``self`` where ``mask`` ``(E, N)`` is true, ``other`` elsewhere."""
        out = {}
        for f in fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            m = mask.view(*mask.shape, *([1] * (a.dim() - 2)))
            out[f.name] = torch.where(m, a, b)
        return AgentState(**out)

    def reset(self, mask: Tensor) -> AgentState:
        """Clear the agents where ``mask`` ``(E, N)`` bool is true (new episode)."""
        if not bool(mask.any()):
            return self
        return self.where(~mask, self.apply(torch.zeros_like))

    def detach(self) -> AgentState:
        """Cut the autograd graph (between rollout steps / PPO sequences)."""
        return self.apply(Tensor.detach)

    def to(self, device: torch.device | str) -> AgentState:
        """Move every tensor to ``device``."""
        return self.apply(lambda t: t.to(device))

    def select_envs(self, index: Tensor | slice) -> AgentState:
        """The state of a subset of environments (for minibatches of sequences)."""
        return self.apply(lambda t: t[index])

    @classmethod
    def cat(cls, states: Sequence[AgentState]) -> AgentState:
        """The states of several env batches joined along the env axis."""
        return cls(**{f.name: torch.cat([getattr(s, f.name) for s in states])
                      for f in fields(cls)})
