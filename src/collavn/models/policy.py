"""The actor-critic: encoders → map → communication → GRU cores → actor / critic heads.

Observation contract (one dict of batched tensors, ``E`` envs × ``N`` agents; any N):

* ``panorama`` uint8 ``(E, N, 3, H, W)`` — 360° cylindrical, heading at the centre column;
* ``goal`` uint8 ``(E, N, 3, Hg, Wg)``;
* ``pose_delta`` float ``(E, N, 3)`` — (dx, dy, dyaw) since the previous step, in the
  agent's previous frame (x forward, y left, yaw CCW);
* ``active`` bool ``(E, N)`` — still running; inactive agents neither request nor
  support, their memory is not written and their state is carried unchanged;
* ``depth`` float ``(E, N, H, W)`` — optional, used iff ``MapConfig.use_depth``;
* ``free_space`` float ``(E, N, D)`` metres — used iff ``ModelConfig.free_space_input``;
* ``explore_action`` float ``(E, N, 2)`` — used iff ``ModelConfig.explore_prior``: the
  explorer's move, added to the actor's means and appended to the map vector.

``gt_map`` is never an input: it supervises the map predictor through
:func:`collavn.models.mapping.map_loss` on ``PolicyStep.map_logits``.

``episode_start`` bool ``(E, N)`` marks observations that begin a new episode; the state
of those agents is cleared *before* the observation is used (odometry ignored).

Actions: a diagonal Gaussian over R² (state-independent learned log-std), or with
``ModelConfig.action_modes = K > 1`` a mixture of K such Gaussians (learned weights,
shared σ; :class:`ActionMixture`). The env gets ``clip(raw, -1, 1)``; log-probabilities
and entropies are those of the *unclipped* raw sample, which PPO must store and pass back
to :meth:`ActorCritic.evaluate_actions`. The deterministic action is
:func:`action_mean`: the Gaussian's mean, the most probable component's mean.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.distributions import Categorical, Distribution, Independent, MixtureSameFamily, Normal

from collavn.envs.free_space import FREE_SPACE_RANGE
from collavn.models.communication import (
    CommProjections,
    Message,
    match_and_select,
    memory_mask,
    plan_memory,
    pooled_past_values,
    silent_message,
)
from collavn.models.config import ModelConfig
from collavn.models.frames import FramePerception
from collavn.models.mapping import MapBuilder, MapEncoder, blend_features
from collavn.models.state import AgentState

ACTION_DIM = 2

#: Percepts of one step, ``name → (E, N, ...)`` tensors (see :meth:`ActorCritic.perceive`).
Percepts = dict[str, Tensor]
#: Outputs of the frame perception (panorama and goal embeddings).
FRAME_PERCEPTS = ("o", "g")
#: What the map tracking makes of a step: the egocentric window of the map channels
#: ``(4, e, e)``, the fraction of each feature cell seen ``(1, G, G)`` and the pose ``(3,)``.
#: With ``MapConfig.detach`` no parameter is on their path, so a rollout stores them and
#: an update never re-runs the map registration (see :meth:`ActorCritic.evaluate_actions`).
MAP_TRACK = ("map_window", "map_seen", "map_pose")


class AgentTower(FramePerception):
    """All weights of one agent (or of every agent when parameters are shared).

    Its frame perception (panorama / goal encoders, goal matcher) comes from
    :class:`~collavn.models.frames.FramePerception`, with the same parameter names.
    """

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__(cfg)
        emb, goal = self.embed_size, self.goal_size
        map_dim = (cfg.map.embed_dim + (3 if cfg.odometry_input else 0) + cfg.free_space_input
                   + (ACTION_DIM if cfg.explore_prior else 0))
        self.odometry_input = cfg.odometry_input
        self.free_space_input = cfg.free_space_input
        self.explore_prior = cfg.explore_prior
        self.map_vector_size = map_dim  # S fed to the cores: map, odometry, free space, prior
        self.map_builder = MapBuilder(cfg.map, cfg.panorama_shape)
        self.map_encoder = MapEncoder(cfg.map)
        self.comm = (None if cfg.comm.variant == "none"
                     else CommProjections(cfg.comm, emb + map_dim))
        msg = 0 if self.comm is None else self.comm.output_size
        critic_in = emb + msg + (map_dim + goal if cfg.critic_full_input else 0)
        self.critic_full_input = cfg.critic_full_input
        self.critic_gradient = cfg.comm.critic_gradient
        self.actor_core = nn.GRUCell(emb + goal + map_dim + msg, cfg.hidden_size)
        self.critic_core = nn.GRUCell(critic_in, cfg.critic_hidden_size)
        modes = self.action_modes = cfg.action_modes
        self.actor_mean = nn.Linear(cfg.hidden_size, ACTION_DIM * modes)
        nn.init.orthogonal_(self.actor_mean.weight, gain=0.01)
        nn.init.zeros_(self.actor_mean.bias)
        # K > 1: mixture weights, and components that start apart — turning from hard
        # right to hard left — so each can take one side of a choice from the first update
        self.actor_modes = nn.Linear(cfg.hidden_size, modes) if modes > 1 else None
        if self.actor_modes is not None:
            nn.init.orthogonal_(self.actor_modes.weight, gain=0.01)
            nn.init.zeros_(self.actor_modes.bias)
            with torch.no_grad():
                self.actor_mean.bias.view(modes, ACTION_DIM)[:, 1] = torch.linspace(
                    -0.5, 0.5, modes)
        self.critic_value = nn.Linear(cfg.critic_hidden_size, 1)
        self.log_std = nn.Parameter(torch.full((ACTION_DIM,), cfg.log_std_init))
        # where the goal is (K sector logits + log distance), read off the actor's state
        self.goal_belief = (nn.Linear(cfg.hidden_size, cfg.goal_belief + 1)
                            if cfg.goal_belief else None)

    def predict_map(self, panorama: Tensor, depth: Tensor | None) -> tuple[Tensor, Tensor]:
        """Local-map logits ``(B, 2, m, m)`` and predictor trunk ``(B, hidden)``."""
        return self.map_builder.predict(panorama, depth)

    def track_map(self, logits: Tensor, pose_delta: Tensor, grid: Tensor, pose: Tensor,
                  first: Tensor) -> tuple[Tensor, ...]:
        """Register the predicted patch into the map channels for ``B`` agents.

        Returns:
            grid ``(B, 4, S, S)``, seen ``(B, 1, G, G)``, pose ``(B, 3)`` and the
            egocentric window of the grid ``(B, 4, e, e)`` the map encoder reads.
        """
        grid_t, seen, pose_t = self.map_builder.track(logits, pose_delta, grid, pose, first)
        return grid_t, seen, pose_t, self.map_encoder.grid_window(grid_t, pose_t)

    def map_visual(self, hidden: Tensor) -> tuple[Tensor]:
        """This step's visual feature ``(B, F)`` for the map's feature grid."""
        return (self.map_builder.visual(hidden),)

    def embed_map(self, window: Tensor, features: Tensor, pose: Tensor, pose_delta: Tensor,
                  first: Tensor, free_space: Tensor | None = None,
                  prior: Tensor | None = None) -> tuple[Tensor]:
        """The map vector ``(B, map_embed [+ 3 odometry] [+ D free space] [+ 2 prior])``.

        From the grid's egocentric window, the feature grid and the pose; free space in
        metres ``(B, D)`` enters as a fraction of the sensor's range, the explorer's
        move ``prior (B, 2)`` as it is.
        """
        s = self.map_encoder.encode(window, self.map_encoder.feature_window(features, pose))
        if self.odometry_input:  # last step's motion, zero at an episode's first step
            s = torch.cat([s, pose_delta * (~first).to(pose_delta.dtype)[:, None]], dim=1)
        if self.free_space_input:
            if free_space is None or free_space.shape[-1] != self.free_space_input:
                got = None if free_space is None else free_space.shape[-1]
                raise ValueError(f"the model reads {self.free_space_input} free-space "
                                 f"directions; the observation has {got} "
                                 f"(EnvConfig.free_space)")
            s = torch.cat([s, free_space.to(s.dtype) / FREE_SPACE_RANGE], dim=1)
        if self.explore_prior:
            s = torch.cat([s, explore_prior(prior).to(s.dtype)], dim=1)
        return (s,)

    def core_inputs(self, o: Tensor, g: Tensor, s: Tensor, omega: Tensor,
                    critic_omega: Tensor) -> tuple[Tensor, Tensor]:
        """The input halves of the GRU cores, ``W_ih x + b_ih``.

        For π(O, S, ω, g) and V(O, ω' [, S, g]), ω' the critic's ω (ω itself unless
        ``CommConfig.critic_hears`` or ``actor_hears`` is off); they need no recurrent
        state, so a replay computes every step at once.
        """
        heard = critic_omega if self.critic_gradient else critic_omega.detach()
        critic_x = [o, heard] + ([s, g] if self.critic_full_input else [])
        return (F.linear(torch.cat([o, s, omega, g], dim=-1), self.actor_core.weight_ih,
                         self.actor_core.bias_ih),
                F.linear(torch.cat(critic_x, dim=-1), self.critic_core.weight_ih,
                         self.critic_core.bias_ih))

    def core_step(self, actor_in: Tensor, critic_in: Tensor, actor_h: Tensor,
                  critic_h: Tensor) -> tuple[Tensor, Tensor]:
        """One step of both GRU cores from their :meth:`core_inputs`."""
        return gru_step(self.actor_core, actor_in, actor_h), gru_step(self.critic_core,
                                                                      critic_in, critic_h)

    def heads(self, actor_h: Tensor, critic_h: Tensor, prior: Tensor | None = None
              ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Actor and critic heads: means, log_std, mixture logits and the value.

        Shapes ``(B, K, 2)``, ``(B, K, 2)``, ``(B, K)`` (zeros for K = 1) and ``(B,)``.
        With ``explore_prior`` every mean is the explorer's move ``prior (B, 2)`` plus
        the head's output.
        """
        mean = self.actor_mean(actor_h).unflatten(-1, (self.action_modes, ACTION_DIM))
        if self.explore_prior:
            mean = mean + explore_prior(prior).to(mean.dtype).unsqueeze(-2)
        logits = (mean.new_zeros(mean.shape[:-1]) if self.actor_modes is None
                  else self.actor_modes(actor_h))
        return (mean, self.log_std.expand_as(mean), logits,
                self.critic_value(critic_h).squeeze(-1))

    def belief(self, actor_h: Tensor) -> tuple[Tensor]:
        """``(B, K + 1)``: the goal-belief head on the actor's state (see :mod:`.belief`)."""
        assert self.goal_belief is not None
        return (self.goal_belief(actor_h),)


def explore_prior(prior: Tensor | None) -> Tensor:
    """The ``explore_action`` observation ``(B, 2)``, or an error naming the env setting."""
    if prior is None or prior.shape[-1] != ACTION_DIM:
        got = None if prior is None else tuple(prior.shape)
        raise ValueError(f"the model adds the explorer's move to its actions "
                         f"(ModelConfig.explore_prior); the observation's explore_action "
                         f"is {got} (EnvConfig.explore_action)")
    return prior


class ActionMixture(MixtureSameFamily):
    """A mixture of diagonal Gaussians over raw actions (``ModelConfig.action_modes``).

    Its entropy (no closed form) is the upper bound H(weights) + Σ_k w_k H(component k),
    which PPO's entropy bonus uses; :func:`action_mean` is the most probable component's
    mean.
    """

    def entropy(self) -> Tensor:
        """H(weights) + Σ_k w_k H(N_k) (≥ the mixture's entropy)."""
        weights = self.mixture_distribution
        return weights.entropy() + (weights.probs
                                    * self.component_distribution.entropy()).sum(-1)


def action_distribution(mean: Tensor, log_std: Tensor, logits: Tensor) -> Distribution:
    """The policy's distribution from :meth:`AgentTower.heads` (any leading batch shape).

    One component: the diagonal Gaussian itself (bit-identical to a model without
    modes); more: an :class:`ActionMixture`.
    """
    if mean.shape[-2] == 1:
        return Independent(Normal(mean[..., 0, :], log_std[..., 0, :].exp()), 1)
    return ActionMixture(Categorical(logits=logits),
                         Independent(Normal(mean, log_std.exp()), 1))


def action_components(dist: Distribution) -> tuple[Tensor, Tensor, Tensor]:
    """Means and stds ``(..., K, 2)`` and mixture logits ``(..., K)`` of a distribution.

    Of :func:`action_distribution`'s output; the Gaussian is one component, logit 0.
    """
    if isinstance(dist, ActionMixture):
        normal = cast(Independent, dist.component_distribution).base_dist
        return normal.loc, normal.scale, dist.mixture_distribution.logits
    normal = cast(Independent, dist).base_dist
    return (normal.loc.unsqueeze(-2), normal.scale.unsqueeze(-2),
            normal.loc.new_zeros(*normal.loc.shape[:-1], 1))


def pick_component(loc: Tensor, scale: Tensor, logits: Tensor, u: Tensor | None = None
                   ) -> tuple[Tensor, Tensor]:
    """Mean and std ``(..., 2)`` of one component of :func:`action_components`' output.

    ``u`` ``(...)`` uniform in [0, 1) picks component k with its weight's probability
    (inverse CDF: a sample of the mixture is then ``mean + std · ε``); without it, the most
    probable component.
    """
    if u is None:
        k = logits.argmax(-1)
    else:
        below = torch.softmax(logits, -1).cumsum(-1) <= u.unsqueeze(-1)
        k = below.sum(-1).clamp(max=logits.shape[-1] - 1)
    index = k[..., None, None].expand(*k.shape, 1, ACTION_DIM)
    return loc.gather(-2, index).squeeze(-2), scale.gather(-2, index).squeeze(-2)


def action_mean(dist: Distribution) -> Tensor:
    """The deterministic action: the Gaussian's mean, or the most probable component's."""
    return pick_component(*action_components(dist))[0]


def gru_step(cell: nn.GRUCell, gates_in: Tensor, h: Tensor) -> Tensor:
    """``cell(x, h)`` given ``gates_in = W_ih x + b_ih`` (PyTorch's GRU equations)."""
    gates_h = F.linear(h, cell.weight_hh, cell.bias_hh)
    in_r, in_z, in_n = gates_in.chunk(3, dim=-1)
    h_r, h_z, h_n = gates_h.chunk(3, dim=-1)
    r = torch.sigmoid(in_r + h_r)
    z = torch.sigmoid(in_z + h_z)
    n = torch.tanh(in_n + r * h_n)
    return n + z * (h - n)


@dataclass(frozen=True)
class PolicyStep:
    """Output of :meth:`ActorCritic.forward`.

    Attributes:
        dist: Distribution over raw actions, batch shape ``(E, N)``, event shape ``(2,)``
            (:func:`action_distribution`).
        value: ``(E, N)`` critic value.
        state: The new recurrent state.
        map_logits: ``(E, N, 2, m, m)`` local map prediction (for ``map_loss``); ``None``
            when the step was replayed from stored map percepts without them.
        message: The communication round (ω, scores, links, bytes sent).
        percepts: This step's percepts (:meth:`ActorCritic.perceive`).
    """

    dist: Distribution
    value: Tensor
    state: AgentState
    map_logits: Tensor | None
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
        target_log_prob: ``(T, E, N)`` log-probability of the ``targets`` passed to
            :meth:`ActorCritic.evaluate_actions` (an expert's actions), if any.
        belief: ``(T, E, N, K + 1)`` the goal-belief head's output
            (``ModelConfig.goal_belief``; ``None`` without the head).
        scores: ``(T, E, N, N)`` the communication scores s_{n,m} (with gradients),
            when :meth:`ActorCritic.evaluate_actions` was asked for them.
    """

    log_prob: Tensor
    entropy: Tensor
    value: Tensor
    target_log_prob: Tensor | None = None
    belief: Tensor | None = None
    scores: Tensor | None = None


@dataclass(frozen=True)
class Unrolled:
    """``T`` steps of :meth:`ActorCritic.forward` (internal).

    Attributes:
        mean: ``(T, E, N, K, 2)``; log_std: ``(T, E, N, K, 2)``; logits:
        ``(T, E, N, K)``; value: ``(T, E, N)``.
        state: The state after the last step (its ``grid`` and ``pose`` are the ones
            before the first step when the map tracking came from stored percepts:
            nothing re-tracked them; :meth:`ActorCritic.evaluate_actions` drops it).
        percepts: Every percept of every step, ``(T, E, N, ...)``.
        messages: The communication round of each step.
        actor_h: ``(T, E, N, hidden)`` the actor's state after each step.
    """

    mean: Tensor
    log_std: Tensor
    logits: Tensor
    value: Tensor
    state: AgentState
    percepts: Percepts
    messages: list[Message]
    actor_h: Tensor


class ActorCritic(nn.Module):
    """Decentralised agents that build maps, talk, and act; weights shared by default."""

    def __init__(self, cfg: ModelConfig, device: torch.device | str | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        copies = cfg.max_agents if cfg.per_agent_params else 1
        self.towers = nn.ModuleList([AgentTower(cfg) for _ in range(copies)])
        self.frames_frozen = False
        self.listen = cfg.comm.listen
        """``False`` cuts the links to teammates (an ablation of what the messages add;
        see :func:`~collavn.models.communication.match_and_select`): from
        ``CommConfig.listen`` (trained so), or set by ``collavn evaluate --mute``."""
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

        ``o, g`` when the frame perception is frozen (:meth:`freeze_frames`); with
        ``MapConfig.detach`` (the predictor learns only from its own supervised updates,
        which run between policy updates) the predictor's trunk ``map_hidden`` and the
        map tracking :data:`MAP_TRACK`. Recomputing a stored percept in a PPO epoch would
        give the same numbers at a CNN's (or a map registration's) cost.
        """
        return ((FRAME_PERCEPTS if self.frames_frozen else ())
                + (("map_hidden", *MAP_TRACK) if self.cfg.map.detach else ()))

    def replay_keys(self) -> tuple[str, ...]:
        """Observation entries :meth:`evaluate_actions` needs beside the stored percepts."""
        keys = (["pose_delta", "active"] + (["free_space"] if self.cfg.free_space_input else [])
                + (["explore_action"] if self.cfg.explore_prior else []))
        if not self.frames_frozen:
            keys += ["panorama", "goal"] + (["depth"] if self.cfg.frame_depth else [])
        if not self.cfg.map.detach:
            keys += ["panorama"] + (["depth"] if self.cfg.map.use_depth else [])
        return tuple(dict.fromkeys(keys))

    def perceive(self, obs: Mapping[str, Tensor], stored: Mapping[str, Tensor] | None = None
                 ) -> Percepts:
        """The percepts of one step (or of ``T·E`` flattened steps) that are not stored.

        ``o (E, N, embed)``, ``g (E, N, goal)``, ``map_hidden (E, N, hidden)`` and, unless
        the map tracking :data:`MAP_TRACK` is stored, ``map_logits (E, N, 2, m, m)``.
        """
        out = dict(stored or {})
        if not all(k in out for k in FRAME_PERCEPTS):
            out["o"], out["g"] = self._dispatch(AgentTower.see, obs["panorama"], obs["goal"],
                                                obs.get("depth"))
        tracked = all(k in out for k in MAP_TRACK)
        if "map_hidden" not in out or not (tracked or "map_logits" in out):
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
        run = self._unroll({k: v[None] for k, v in obs.items()}, state, episode_start[None],
                           None if percepts is None else {k: v[None] for k, v in
                                                          percepts.items()})
        dist = action_distribution(run.mean[0], run.log_std[0], run.logits[0])
        p = {k: v[0] for k, v in run.percepts.items()}
        return PolicyStep(dist, run.value[0], run.state, p.get("map_logits"),
                          run.messages[0], p)

    @torch.no_grad()
    def act(self, obs: Mapping[str, Tensor], state: AgentState, episode_start: Tensor,
            deterministic: bool = False) -> ActOutput:
        """Sample (or take the mean of) the policy for one step, without gradients."""
        step = self(obs, state, episode_start)
        raw = action_mean(step.dist) if deterministic else step.dist.sample()
        return ActOutput(raw.clamp(-1.0, 1.0), raw, step.dist.log_prob(raw), step.value,
                         step.state, step.message.bytes_sent, step.message, step.percepts)

    def evaluate_actions(self, obs: Mapping[str, Tensor], state: AgentState,
                         episode_start: Tensor, raw_actions: Tensor,
                         percepts: Mapping[str, Tensor] | None = None,
                         targets: Tensor | None = None,
                         scores: bool = False) -> EvaluateOutput:
        """Re-run stored sequences for recurrent PPO (and imitation).

        The networks without a recurrence (encoders, map encoder, feature projection) run
        once over all ``T·E·N`` steps; only the communication and the GRU cores step
        through time. With the frame perception frozen and ``MapConfig.detach`` the
        stored percepts replace every image and every map registration.

        Args:
            obs: Observation dict with a leading time axis, every entry ``(T, E, N, ...)``
                (only :meth:`replay_keys` are read when ``percepts`` holds
                :attr:`stored_percepts`).
            state: The state before the first step (stored at rollout time, detached).
            episode_start: ``(T, E, N)`` bool.
            raw_actions: ``(T, E, N, 2)`` unclipped actions from :meth:`act`.
            percepts: Stored percepts ``(T, E, N, ...)`` (see :meth:`forward`).
            targets: ``(T, E, N, 2)`` other actions to score (PPO's behaviour-cloning
                term: the expert's actions), under the same distribution with its σ
                detached: only the means (and mixture weights) learn from them.
            scores: Also return every step's communication scores (PPO's message
                floor, ``--ppo.message-floor``).
        """
        run = self._unroll(obs, state, episode_start, percepts)
        dist = action_distribution(run.mean, run.log_std, run.logits)
        target_log_prob = None
        if targets is not None:
            target_log_prob = action_distribution(run.mean, run.log_std.detach(),
                                                  run.logits).log_prob(targets)
        belief = (self._over_steps(AgentTower.belief, run.actor_h)[0]
                  if self.cfg.goal_belief else None)
        return EvaluateOutput(dist.log_prob(raw_actions), dist.entropy(), run.value,
                              target_log_prob, belief,
                              torch.stack([m.scores for m in run.messages]) if scores
                              else None)

    @torch.no_grad()
    def mean_actions(self, obs: Mapping[str, Tensor], state: AgentState,
                     episode_start: Tensor, percepts: Mapping[str, Tensor] | None = None
                     ) -> tuple[Tensor, AgentState]:
        """The deterministic actions :meth:`act` would take along stored sequences.

        Inputs as :meth:`evaluate_actions`. Returns the raw (unclipped) actions
        ``(T, E, N, 2)`` and the state after the last step (its map ``grid`` and ``pose``
        stay as given when the stored percepts hold the map tracking: nothing reads them
        then).
        """
        run = self._unroll(obs, state, episode_start, percepts)
        return action_mean(action_distribution(run.mean, run.log_std, run.logits)), run.state

    def _unroll(self, obs: Mapping[str, Tensor], state: AgentState, starts: Tensor,
                stored: Mapping[str, Tensor] | None) -> Unrolled:
        """``T`` decision steps from ``(T, E, N, ...)`` inputs (see :meth:`forward`)."""
        steps, e, n = starts.shape
        active = obs["active"].bool()
        if self.cfg.per_agent_params and n > len(self.towers):
            raise ValueError(f"{n} agents but only {len(self.towers)} "
                             "per-agent parameter sets (ModelConfig.max_agents)")
        flat = {k: v.reshape(steps * e, *v.shape[2:]) for k, v in obs.items()}
        p = {k: v.reshape(steps, e, *v.shape[1:]) for k, v in self.perceive(
            flat, None if stored is None else
            {k: v.reshape(steps * e, *v.shape[2:]) for k, v in stored.items()}).items()}
        delta = obs["pose_delta"].float()

        # Most steps have every agent active and none starting: then these are the
        # identity and skip copying the (E, N, 4, S, S) map (~10 % of a collection step).
        any_start = starts.flatten(1).any(dim=1).tolist()
        all_active = active.flatten(1).all(dim=1).tolist()

        def carry(mask: Tensor, new: Tensor, old: Tensor) -> Tensor:
            return torch.where(mask.view(*mask.shape, *([1] * (new.dim() - 2))), new, old)

        def kept(t: int, new: Tensor, old: Tensor) -> Tensor:  # inactive agents keep old
            return new if all_active[t] else carry(active[t], new, old)

        def cleared(x: Tensor, t: int) -> Tensor:  # an episode start clears the state
            return carry(starts[t], torch.zeros_like(x), x) if any_start[t] else x

        grid, pose = state.grid, state.pose
        if not all(k in p for k in MAP_TRACK):
            tracked: list[tuple[Tensor, ...]] = []
            for t in range(steps):
                grid, pose = cleared(grid, t), cleared(pose, t)
                grid_t, seen, pose_t, window = self._dispatch(
                    AgentTower.track_map, p["map_logits"][t], delta[t], grid, pose,
                    starts[t])
                tracked.append((window, seen, pose_t))
                grid, pose = kept(t, grid_t, grid), kept(t, pose_t, pose)
            for key, parts in zip(MAP_TRACK, zip(*tracked, strict=True), strict=True):
                p[key] = torch.stack(parts)
        # per-step slices by unbind: indexing [t] in a loop would make autograd add a
        # full-size zero tensor per step in the backward pass (O(T²) memory traffic)
        visual = self._over_steps(AgentTower.map_visual, p["map_hidden"])[0].unbind(0)
        seen_t = p["map_seen"].unbind(0)
        features, blended = state.features, []
        for t in range(steps):
            f = cleared(features, t)
            f_t = blend_features(f, seen_t[t], visual[t])
            blended.append(f_t)
            features = kept(t, f_t, f)
        s = self._over_steps(AgentTower.embed_map, p["map_window"], torch.stack(blended),
                             p["map_pose"], delta, starts, obs.get("free_space"),
                             obs.get("explore_action"))[0]
        # communication needs no GRU state: every step at once
        messages, omega, critic_omega, talk = self._communicate(p["o"], s, state, starts,
                                                                active)
        actor_in, critic_in = (x.unbind(0) for x in self._over_steps(
            AgentTower.core_inputs, p["o"], p["g"], s, omega, critic_omega))
        actor_h, critic_h, actor_hs, critic_hs = state.actor_h, state.critic_h, [], []
        for t in range(steps):
            a_h, c_h = cleared(actor_h, t), cleared(critic_h, t)
            a_new, c_new = self._dispatch(AgentTower.core_step, actor_in[t], critic_in[t],
                                          a_h, c_h)
            actor_hs.append(a_new)
            critic_hs.append(c_new)
            actor_h, critic_h = kept(t, a_new, a_h), kept(t, c_new, c_h)
        actor_seq = torch.stack(actor_hs)
        mean, log_std, logits, value = self._over_steps(
            AgentTower.heads, actor_seq, torch.stack(critic_hs), obs.get("explore_action"))
        final = replace(talk, actor_h=actor_h, critic_h=critic_h, grid=grid,
                        features=features, pose=pose)
        return Unrolled(mean, log_std, logits, value, final, p, messages, actor_seq)

    def _over_steps(self, fn: Callable[..., tuple[Tensor, ...]],
                    *args: Tensor | None) -> tuple[Tensor, ...]:
        """:meth:`_dispatch` over ``(T, E, N, ...)`` inputs, as one batch of ``T·E`` envs."""
        ref = next(a for a in args if a is not None)
        steps, e = ref.shape[:2]
        outs = self._dispatch(fn, *[None if a is None else a.reshape(steps * e, *a.shape[2:])
                                    for a in args])
        return tuple(out.reshape(steps, e, *out.shape[1:]) for out in outs)

    def _communicate(self, o: Tensor, s: Tensor, state: AgentState, starts: Tensor,
                     active: Tensor) -> tuple[list[Message], Tensor, Tensor, AgentState]:
        """Request, store, match and select for ``T`` steps (``(T, E, N, ...)`` inputs).

        See :mod:`collavn.models.communication`. Nothing here is recurrent but the
        memory, and the memory holds only earlier steps' keys and values: those are
        computed for all steps at once, :func:`plan_memory` says which of them (or of the
        memory before the sequence) fill every slot at every step, and all steps are
        matched as one batch. One step at collection and the same step replayed by PPO
        go through the same operations (the first epoch's log-probs are exact, up to the
        last bit where a CPU's vectorised sigmoid rounds by an element's place in the
        loop).

        Returns:
            Each step's message (what teammates send, read by whichever of actor and
            critic hears them), the actor's ω ``(T, E, N, value_dim)``, the critic's ω
            (the same tensor unless ``CommConfig.critic_hears`` or ``actor_hears`` is
            off: then that one is the ω of each agent's own entries alone), and
            ``state`` with the memory, counts and steps after the last step.
        """
        cfg = self.cfg.comm
        steps, e, n = starts.shape
        plan = plan_memory(state.mem_count, state.steps, starts, active,
                           state.mem_keys.shape[2], cfg.store_interval,
                           cfg.variant == "memory")
        if cfg.variant == "none":
            messages = [silent_message(active[t], 0, o.dtype) for t in range(steps)]
            omega = critic_omega = o.new_zeros(steps, e, n, 0)
        else:
            x = torch.cat([o, s], dim=-1)
            key, value = self._over_steps(lambda t, x_: t.comm.key_value(x_), x)
            # every step's memory after its write, then its own entry: L = S + 1 rows
            keys = plan.entries(state.mem_keys, key)
            values = plan.entries(state.mem_values, value).gathered()  # read twice
            slots = keys.index.shape[3] - 1
            stored = memory_mask(plan.count, slots)
            own = torch.zeros_like(plan.write).unsqueeze(-1)  # (T, E, N, 1) bool
            pooled = pooled_past_values(values, torch.cat([stored & ~plan.slot, own], dim=3))
            query, bias = self._over_steps(lambda t, x_, p_: t.comm.query_psi(x_, p_), x,
                                           pooled)
            matched = torch.cat([stored, ~plan.write.unsqueeze(-1)], dim=3)
            msg = match_and_select(query, bias, keys, values, matched, active, cfg,
                                   teammates=self.listen)
            parts = [f.unbind(0) for f in (msg.omega, msg.scores, msg.gates, msg.self_open,
                                           msg.links, msg.bytes_sent)]
            messages = [Message(*fields) for fields in zip(*parts, strict=True)]
            omega = critic_omega = msg.omega
            if self.listen and not (cfg.critic_hears and cfg.actor_hears):
                deaf = match_and_select(query, bias, keys, values, matched, active, cfg,
                                        teammates=False)  # the match a deaf agent makes
                if not cfg.critic_hears:
                    critic_omega = deaf.omega
                if not cfg.actor_hears:
                    omega = deaf.omega
            state = replace(state, mem_keys=keys.step(-1)[:, :, :slots],
                            mem_values=values.step(-1)[:, :, :slots])
        return messages, omega, critic_omega, replace(state, mem_count=plan.count[-1],
                                                      steps=plan.steps)

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
