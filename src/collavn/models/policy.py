"""The actor-critic: encoders → map → communication → GRU cores → actor / critic heads.

Observation contract (one dict of batched tensors, ``E`` envs × ``N`` agents; any N):

* ``panorama`` uint8 ``(E, N, 3, H, W)`` — 360° cylindrical, heading at the centre column;
* ``goal`` uint8 ``(E, N, 3, Hg, Wg)``;
* ``pose_delta`` float ``(E, N, 3)`` — (dx, dy, dyaw) since the previous step, in the
  agent's previous frame (x forward, y left, yaw CCW);
* ``active`` bool ``(E, N)`` — still running; inactive agents neither request nor
  support, their memory is not written and their state is carried unchanged;
* ``depth`` float ``(E, N, H, W)`` — optional, used iff ``MapConfig.use_depth``.

``gt_map`` is never an input: it supervises the map predictor through
:func:`collavn.models.mapping.map_loss` on ``PolicyStep.map_logits``.

``episode_start`` bool ``(E, N)`` marks observations that begin a new episode; the state
of those agents is cleared *before* the observation is used (odometry ignored).

Actions: a diagonal Gaussian over R² (state-independent learned log-std). The env gets
``clip(raw, -1, 1)``; log-probabilities and entropies are those of the *unclipped* raw
sample, which PPO must store and pass back to :meth:`ActorCritic.evaluate_actions`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import cast

import torch
from torch import Tensor, nn
from torch.distributions import Independent, Normal

from collavn.models.communication import (
    CommProjections,
    Message,
    match_and_select,
    memory_mask,
    pooled_past_values,
    silent_message,
    write_memory,
)
from collavn.models.config import ModelConfig
from collavn.models.frames import FramePerception
from collavn.models.mapping import MapBuilder, MapEncoder
from collavn.models.state import AgentState

ACTION_DIM = 2

#: Percepts of one step, ``name → (E, N, ...)`` tensors (see :meth:`ActorCritic.perceive`).
Percepts = dict[str, Tensor]
#: Outputs of the frame perception (panorama and goal embeddings).
FRAME_PERCEPTS = ("o", "g")
#: Outputs of the local-map predictor (logits of the local patch and its trunk features).
MAP_PERCEPTS = ("map_logits", "map_hidden")


class AgentTower(FramePerception):
    """All weights of one agent (or of every agent when parameters are shared).

    Its frame perception (panorama / goal encoders, goal matcher) comes from
    :class:`~collavn.models.frames.FramePerception`, with the same parameter names.
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        emb, goal = self.embed_size, self.goal_size
        map_dim = cfg.map.embed_dim + (3 if cfg.odometry_input else 0)
        self.odometry_input = cfg.odometry_input
        self.map_builder = MapBuilder(cfg.map, cfg.panorama_shape)
        self.map_encoder = MapEncoder(cfg.map)
        self.comm = (None if cfg.comm.variant == "none"
                     else CommProjections(cfg.comm, emb + map_dim))
        msg = 0 if self.comm is None else self.comm.output_size
        critic_in = emb + msg + (map_dim + goal if cfg.critic_full_input else 0)
        self.critic_full_input = cfg.critic_full_input
        self.actor_core = nn.GRUCell(emb + goal + map_dim + msg, cfg.hidden_size)
        self.critic_core = nn.GRUCell(critic_in, cfg.critic_hidden_size)
        self.actor_mean = nn.Linear(cfg.hidden_size, ACTION_DIM)
        nn.init.orthogonal_(self.actor_mean.weight, gain=0.01)
        nn.init.zeros_(self.actor_mean.bias)
        self.critic_value = nn.Linear(cfg.critic_hidden_size, 1)
        self.log_std = nn.Parameter(torch.full((ACTION_DIM,), cfg.log_std_init))

    def predict_map(self, panorama: Tensor, depth: Tensor | None) -> tuple[Tensor, Tensor]:
        """Local-map logits ``(B, 2, m, m)`` and predictor trunk ``(B, hidden)``."""
        return self.map_builder.predict(panorama, depth)

    def build_map(self, logits: Tensor, hidden: Tensor, pose_delta: Tensor, grid: Tensor,
                  features: Tensor, pose: Tensor, first: Tensor) -> tuple[Tensor, ...]:
        """Fuse the predicted patch into the map and encode it for ``B`` agents.

        Returns:
            The map vector ``(B, map_embed [+ 3 odometry])`` and the map step: grid
            ``(B, 4, S, S)``, features ``(B, F, G, G)``, pose ``(B, 3)``.
        """
        step = self.map_builder.update(logits, hidden, pose_delta, grid, features, pose,
                                       first)
        s = self.map_encoder(step.grid, step.features, step.pose)
        if self.odometry_input:  # last step's motion, zero at an episode's first step
            s = torch.cat([s, pose_delta * (~first).to(pose_delta.dtype)[:, None]], dim=1)
        return s, step.grid, step.features, step.pose

    def heads(self, o: Tensor, g: Tensor, s: Tensor, omega: Tensor, actor_h: Tensor,
              critic_h: Tensor) -> tuple[Tensor, ...]:
        """GRU cores and heads: π(O, S, ω, g) and V(O, ω).

        Returns:
            mean ``(B, 2)``, log_std ``(B, 2)``, value ``(B,)``, actor_h, critic_h.
        """
        actor_h = self.actor_core(torch.cat([o, s, omega, g], dim=1), actor_h)
        critic_x = [o, omega] + ([s, g] if self.critic_full_input else [])
        critic_h = self.critic_core(torch.cat(critic_x, dim=1), critic_h)
        mean = self.actor_mean(actor_h)
        log_std = self.log_std.expand_as(mean)
        return mean, log_std, self.critic_value(critic_h).squeeze(-1), actor_h, critic_h


@dataclass(frozen=True)
class PolicyStep:
    """Output of :meth:`ActorCritic.forward`.

    Attributes:
        dist: Gaussian over raw actions, batch shape ``(E, N)``, event shape ``(2,)``.
        value: ``(E, N)`` critic value.
        state: The new recurrent state.
        map_logits: ``(E, N, 2, m, m)`` local map prediction (for ``map_loss``).
        message: The communication round (ω, scores, links, bytes sent).
        percepts: This step's percepts (:meth:`ActorCritic.perceive`).
    """

    dist: Independent
    value: Tensor
    state: AgentState
    map_logits: Tensor
    message: Message
    percepts: Percepts


@dataclass(frozen=True)
class ActOutput:
    """Output of :meth:`ActorCritic.act` (no autograd graph).

    Attributes:
        action: ``(E, N, 2)`` in [-1, 1], for the env.
        raw_action: ``(E, N, 2)`` unclipped sample, to store for PPO.
        log_prob: ``(E, N)`` log-probability of ``raw_action``.
        value: ``(E, N)``.
        state: The new recurrent state.
        bytes_sent: ``(E, N)`` communication traffic of each agent this step.
        message: The full communication round.
        percepts: This step's percepts (store those in
            :attr:`ActorCritic.stored_percepts` to replay the step without images).
    """

    action: Tensor
    raw_action: Tensor
    log_prob: Tensor
    value: Tensor
    state: AgentState
    bytes_sent: Tensor
    message: Message
    percepts: Percepts


@dataclass(frozen=True)
class EvaluateOutput:
    """Output of :meth:`ActorCritic.evaluate_actions` over a sequence of ``T`` steps.

    Attributes:
        log_prob: ``(T, E, N)``; entropy: ``(T, E, N)``; value: ``(T, E, N)``.
        state: The state after the last step.
    """

    log_prob: Tensor
    entropy: Tensor
    value: Tensor
    state: AgentState


class ActorCritic(nn.Module):
    """Decentralised agents that build maps, talk, and act; weights shared by default."""

    def __init__(self, cfg: ModelConfig, device: torch.device | str | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        copies = cfg.max_agents if cfg.per_agent_params else 1
        self.towers = nn.ModuleList([AgentTower(cfg) for _ in range(copies)])
        self.frames_frozen = False
        if device is not None:
            self.to(device)

    @property
    def device(self) -> torch.device:
        """Where the parameters live."""
        return next(self.parameters()).device

    def initial_state(self, num_envs: int, num_agents: int) -> AgentState:
        """Zero state for ``num_envs × num_agents`` agents on the model's device."""
        return AgentState.zeros(self.cfg, num_envs, num_agents, device=self.device)

    def freeze_frames(self) -> None:
        """Freeze every tower's frame perception (e.g. after loading a pretrained encoder).

        Its weights stop requiring gradients and its outputs ``o, g`` join
        :attr:`stored_percepts`: a rollout stores them and updates never run it again.
        """
        for tower in self.towers:
            for module in cast(AgentTower, tower).frame_modules():
                module.requires_grad_(False)
        self.frames_frozen = True

    @property
    def stored_percepts(self) -> tuple[str, ...]:
        """Percepts that no policy gradient can change, so a rollout stores them.

        ``o, g`` when the frame perception is frozen (:meth:`freeze_frames`); the local
        map prediction when ``MapConfig.detach`` (the predictor learns only from its own
        supervised updates, which run between policy updates). Recomputing a stored
        percept in a PPO epoch would give the same numbers at a CNN's cost.
        """
        return ((FRAME_PERCEPTS if self.frames_frozen else ())
                + (MAP_PERCEPTS if self.cfg.map.detach else ()))

    def replay_keys(self) -> tuple[str, ...]:
        """Observation entries :meth:`evaluate_actions` needs beside the stored percepts."""
        keys = ["pose_delta", "active"]
        if not self.frames_frozen:
            keys += ["panorama", "goal"]
        if not self.cfg.map.detach:
            keys += ["panorama"] + (["depth"] if self.cfg.map.use_depth else [])
        return tuple(dict.fromkeys(keys))

    def perceive(self, obs: Mapping[str, Tensor], stored: Mapping[str, Tensor] | None = None
                 ) -> Percepts:
        """The percepts of one step; those in ``stored`` are reused, not recomputed.

        ``o (E, N, embed)``, ``g (E, N, goal)``, ``map_logits (E, N, 2, m, m)``,
        ``map_hidden (E, N, hidden)``.
        """
        out = dict(stored or {})
        if not all(k in out for k in FRAME_PERCEPTS):
            out["o"], out["g"] = self._dispatch(AgentTower.see, obs["panorama"], obs["goal"])
        if not all(k in out for k in MAP_PERCEPTS):
            out["map_logits"], out["map_hidden"] = self._dispatch(
                AgentTower.predict_map, obs["panorama"], obs.get("depth"))
        return out

    def forward(self, obs: Mapping[str, Tensor], state: AgentState,
                episode_start: Tensor, percepts: Mapping[str, Tensor] | None = None
                ) -> PolicyStep:
        """One decision step for every agent (see the module docstring for shapes).

        ``percepts``: stored percepts of this step (:meth:`perceive`); images are then
        only read for the percepts not given.
        """
        state = state.reset(episode_start)
        active = obs["active"].bool()
        if self.cfg.per_agent_params and active.shape[1] > len(self.towers):
            raise ValueError(f"{active.shape[1]} agents but only {len(self.towers)} "
                             "per-agent parameter sets (ModelConfig.max_agents)")
        p = self.perceive(obs, percepts)
        s, grid, feats, pose = self._dispatch(
            AgentTower.build_map, p["map_logits"], p["map_hidden"], obs["pose_delta"].float(),
            state.grid, state.features, state.pose, episode_start)
        message, keys, values, count = self._communicate(p["o"], s, state, active)
        mean, log_std, value, actor_h, critic_h = self._dispatch(
            AgentTower.heads, p["o"], p["g"], s, message.omega, state.actor_h, state.critic_h)
        new = AgentState(actor_h, critic_h, grid, feats, pose, keys, values, count,
                         state.steps + 1).where(active, state)
        dist = Independent(Normal(mean, log_std.exp()), 1)
        return PolicyStep(dist, value, new, p["map_logits"], message, p)

    @torch.no_grad()
    def act(self, obs: Mapping[str, Tensor], state: AgentState, episode_start: Tensor,
            deterministic: bool = False) -> ActOutput:
        """Sample (or take the mean of) the policy for one step, without gradients."""
        step = self(obs, state, episode_start)
        raw = step.dist.mean if deterministic else step.dist.sample()
        return ActOutput(raw.clamp(-1.0, 1.0), raw, step.dist.log_prob(raw), step.value,
                         step.state, step.message.bytes_sent, step.message, step.percepts)

    def evaluate_actions(self, obs: Mapping[str, Tensor], state: AgentState,
                         episode_start: Tensor, raw_actions: Tensor,
                         percepts: Mapping[str, Tensor] | None = None) -> EvaluateOutput:
        """Re-run stored sequences for recurrent PPO (and imitation).

        Args:
            obs: Observation dict with a leading time axis, every entry ``(T, E, N, ...)``
                (only :meth:`replay_keys` are read when ``percepts`` holds
                :attr:`stored_percepts`).
            state: The state before the first step (stored at rollout time, detached).
            episode_start: ``(T, E, N)`` bool.
            raw_actions: ``(T, E, N, 2)`` unclipped actions from :meth:`act`.
            percepts: Stored percepts ``(T, E, N, ...)`` (see :meth:`forward`).
        """
        log_probs, entropies, values = [], [], []
        for t in range(raw_actions.shape[0]):
            step = self({k: v[t] for k, v in obs.items()}, state, episode_start[t],
                        None if percepts is None else {k: v[t] for k, v in percepts.items()})
            log_probs.append(step.dist.log_prob(raw_actions[t]))
            entropies.append(step.dist.entropy())
            values.append(step.value)
            state = step.state
        return EvaluateOutput(torch.stack(log_probs), torch.stack(entropies),
                              torch.stack(values), state)

    def _communicate(self, o: Tensor, s: Tensor, state: AgentState,
                     active: Tensor) -> tuple[Message, Tensor, Tensor, Tensor]:
        """Request, store, match and select (see :mod:`collavn.models.communication`)."""
        cfg = self.cfg.comm
        if cfg.variant == "none":
            msg = silent_message(active, 0, o.dtype)
            return msg, state.mem_keys, state.mem_values, state.mem_count
        x = torch.cat([o, s], dim=-1)
        key, value = self._dispatch(lambda t, x_: t.comm.key_value(x_), x)
        write = active & (state.steps % cfg.store_interval == 0)
        if cfg.variant != "memory":
            write = torch.zeros_like(write)
        keys, values, count, slot = write_memory(
            state.mem_keys, state.mem_values, state.mem_count, key, value, write)
        stored = memory_mask(count, keys.shape[2])
        pooled = pooled_past_values(values, stored & ~slot)
        query, bias = self._dispatch(lambda t, x_, p_: t.comm.query_psi(x_, p_), x, pooled)
        entries_k = torch.cat([keys, key.unsqueeze(2)], dim=2)
        entries_v = torch.cat([values, value.unsqueeze(2)], dim=2)
        entry_mask = torch.cat([stored, ~write.unsqueeze(-1)], dim=2)
        msg = match_and_select(query, bias, entries_k, entries_v, entry_mask, active, cfg)
        return msg, keys, values, count

    def _dispatch(self, fn: Callable[..., tuple[Tensor, ...]],
                  *args: Tensor | None) -> tuple[Tensor, ...]:
        """Apply ``fn(tower, *args)`` to ``(E, N, ...)`` inputs, returning ``(E, N, ...)``.

        Shared weights: one call on the flattened ``E·N`` batch. Per-agent weights: one
        call per agent slot ``n`` with tower ``n``.
        """
        ref = next(a for a in args if a is not None)
        e, n = ref.shape[:2]
        if len(self.towers) == 1:
            flat = [None if a is None else a.reshape(e * n, *a.shape[2:]) for a in args]
            outs = fn(self.towers[0], *flat)
            return tuple(out.reshape(e, n, *out.shape[1:]) for out in outs)
        per_agent = [fn(self.towers[i], *[None if a is None else a[:, i] for a in args])
                     for i in range(n)]
        return tuple(torch.stack(parts, dim=1) for parts in zip(*per_agent, strict=True))
