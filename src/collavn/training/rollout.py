"""Rollout storage over ``(T, E, N)`` (steps, envs, agents) and GAE.

One rollout holds ``T`` consecutive steps of ``E`` envs × ``N`` agents, the recurrent
state the rollout started from (recurrent PPO re-runs whole sequences from it) and,
per agent and step, the flags that cut the advantage recursion:

* ``terminated[t]`` — the agent reached its goal with action ``t``: no bootstrap;
* ``truncated[t]`` — its episode hit ``T_max`` with action ``t``: bootstrap. The env
  does not return the last observation of a finished episode (SAME_STEP autoreset), so
  the bootstrap uses the value of the observation at ``t`` (see
  :mod:`collavn.envs.vector`);
* ``active[t]`` — the agent was still running when it acted; steps of agents that
  already finished (waiting for the others) carry no learning signal and are masked.

Stored features: ``percepts`` holds, per step, what no policy gradient can change
(``ActorCritic.stored_percepts``: a frozen pretrained encoder's ``o, g``; with a
detached map predictor its trunk features and the map tracking — the egocentric window
of the map channels, the seen fraction of each feature cell, the pose). ``obs`` then
keeps only what the update still reads (``ActorCritic.replay_keys``) — no images at
all when both are stored — and PPO epochs and imitation updates never run those CNNs
or the map registration again: they run the map encoder once over all steps and step
only the communication and the GRU cores through time.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from collavn.models.state import AgentState


@dataclass
class Rollout:
    """``T`` steps of ``E × N`` agents, every tensor with leading ``(T, E, N)``.

    Attributes:
        obs: Model inputs the update reads, ``(T, E, N, ...)`` each.
        percepts: Stored percepts, ``(T, E, N, ...)`` each (empty: none stored).
        episode_start: ``(T, E, N)`` bool.
        raw_actions: ``(T, E, N, 2)`` unclipped sampled actions (PPO) or expert targets (IL).
        log_probs: ``(T, E, N)`` log-probability of ``raw_actions`` at collection.
        values: ``(T, E, N)`` critic values at collection.
        rewards: ``(T, E, N)``.
        terminated: ``(T, E, N)`` bool.
        truncated: ``(T, E, N)`` bool.
        initial_state: The recurrent state before step 0 (detached).
        last_value: ``(E, N)`` value of the observation after step ``T - 1``.
        expert_actions: ``(T, E, N, 2)`` the expert's actions in the visited states (or,
            with ``--ppo.bc-target init``, the ``--init-from`` policy's mean actions), for
            PPO's behaviour-cloning term (``--ppo.bc-coef``); ``None`` without one.
        belief_labels: ``(T, E, N, 2)`` where the goal was (sector, log distance; see
            :mod:`collavn.models.belief`), for the goal-belief head; ``None`` without it.
        weights: ``(T, E, N)`` per-step weights of ``il``'s likelihood
            (``--imitation.homing-weight``) or of PPO's behaviour-cloning term
            (``--ppo.bc-steps sighted`` or ``blocked``); ``None``: every step weighs 1.
    """

    obs: dict[str, Tensor]
    percepts: dict[str, Tensor]
    episode_start: Tensor
    raw_actions: Tensor
    log_probs: Tensor
    values: Tensor
    rewards: Tensor
    terminated: Tensor
    truncated: Tensor
    initial_state: AgentState
    last_value: Tensor
    expert_actions: Tensor | None = None
    belief_labels: Tensor | None = None
    weights: Tensor | None = None

    @classmethod
    def allocate(cls, steps: int, first_obs: Mapping[str, Tensor], initial_state: AgentState,
                 percepts: Mapping[str, Tensor] | None = None,
                 expert: bool = False, belief: bool = False,
                 weights: bool = False) -> Rollout:
        """Empty storage for ``steps`` steps shaped like one step's ``(E, N, ...)`` inputs.

        ``first_obs`` and ``percepts`` give the entries kept and their shapes; ``expert``
        adds room for the expert's actions, ``belief`` for the goal-belief labels,
        ``weights`` for per-step loss weights (filled with 1).
        """
        e, n = first_obs["active"].shape
        dev = first_obs["active"].device

        def z(*shape: int, dtype: torch.dtype = torch.float32) -> Tensor:
            return torch.zeros(steps, e, n, *shape, dtype=dtype, device=dev)

        obs = {k: torch.zeros(steps, *v.shape, dtype=v.dtype, device=dev)
               for k, v in first_obs.items()}
        stored = {k: torch.zeros(steps, *v.shape, dtype=v.dtype, device=dev)
                  for k, v in (percepts or {}).items()}
        return cls(obs, stored, z(dtype=torch.bool), z(2), z(), z(), z(), z(dtype=torch.bool),
                   z(dtype=torch.bool), initial_state.detach(), torch.zeros(e, n, device=dev),
                   z(2) if expert else None, z(2) if belief else None,
                   z() + 1.0 if weights else None)

    @property
    def steps(self) -> int:
        """T."""
        return self.rewards.shape[0]

    @property
    def active(self) -> Tensor:
        """``(T, E, N)`` bool: the agent acted at that step (the learning mask)."""
        return self.obs["active"].bool()

    def insert(self, t: int, obs: Mapping[str, Tensor], start: Tensor, raw_action: Tensor,
               log_prob: Tensor, value: Tensor,
               percepts: Mapping[str, Tensor] | None = None) -> None:
        """Store what the agents saw (the kept entries) and did at step ``t``."""
        for k in self.obs:
            self.obs[k][t] = obs[k]
        for k in self.percepts:
            self.percepts[k][t] = (percepts or {})[k]
        self.episode_start[t] = start
        self.raw_actions[t] = raw_action
        self.log_probs[t] = log_prob
        self.values[t] = value

    def insert_outcome(self, t: int, reward: np.ndarray, terminated: np.ndarray,
                       truncated: np.ndarray) -> None:
        """Store the env's answer to step ``t``."""
        dev = self.rewards.device
        self.rewards[t] = torch.as_tensor(reward, dtype=torch.float32).to(dev)
        self.terminated[t] = torch.as_tensor(terminated).to(dev)
        self.truncated[t] = torch.as_tensor(truncated).to(dev)

    def select_envs(self, index: Tensor) -> Rollout:
        """The sub-rollout of some envs (all their agents, all steps)."""
        return Rollout({k: v[:, index] for k, v in self.obs.items()},
                       {k: v[:, index] for k, v in self.percepts.items()},
                       self.episode_start[:, index], self.raw_actions[:, index],
                       self.log_probs[:, index], self.values[:, index],
                       self.rewards[:, index], self.terminated[:, index],
                       self.truncated[:, index], self.initial_state.select_envs(index),
                       self.last_value[index],
                       None if self.expert_actions is None else self.expert_actions[:, index],
                       None if self.belief_labels is None else self.belief_labels[:, index],
                       None if self.weights is None else self.weights[:, index])


def compute_gae(rewards: Tensor, values: Tensor, terminated: Tensor, truncated: Tensor,
                last_value: Tensor, gamma: float, gae_lambda: float) -> tuple[Tensor, Tensor]:
    """Generalised advantage estimation over ``(T, E, N)``.

    ``δ_t = r_t + γ·V_next − V_t`` with ``V_next`` = ``V_{t+1}`` (``last_value`` after the
    last step), 0 after ``terminated``, and ``V_t`` after ``truncated`` (the final
    observation is not returned); ``A_t = δ_t + γλ·A_{t+1}`` unless the episode ended
    at ``t``. Steps of inactive agents should be masked by the caller.

    Args:
        rewards: ``(T, E, N)``.
        values: ``(T, E, N)`` critic values of the stored observations.
        terminated: ``(T, E, N)`` bool.
        truncated: ``(T, E, N)`` bool.
        last_value: ``(E, N)`` value of the observation after the last step.
        gamma: Discount γ.
        gae_lambda: λ.

    Returns:
        advantages ``(T, E, N)`` and returns ``advantages + values``.
    """
    ended = (terminated | truncated).float()
    advantages = torch.zeros_like(rewards)
    next_adv = torch.zeros_like(last_value)
    next_value = last_value
    for t in reversed(range(rewards.shape[0])):
        bootstrap = (1.0 - ended[t]) * next_value + truncated[t].float() * values[t]
        delta = rewards[t] + gamma * bootstrap - values[t]
        next_adv = delta + gamma * gae_lambda * (1.0 - ended[t]) * next_adv
        advantages[t] = next_adv
        next_value = values[t]
    return advantages, advantages + values
