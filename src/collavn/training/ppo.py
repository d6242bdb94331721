"""The PPO update: clipped surrogate, value loss and entropy over recurrent sequences.

Decentralized critics: each agent's value comes from its own critic head on its own
input and received message (:class:`collavn.models.policy.AgentTower`); nothing sees
the joint state. Mini-batches are sets of *envs* — every agent of an env for the whole
rollout — because agents of one env talk to each other and the recurrent state runs
along the sequence.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from torch import Tensor

from collavn.models.communication import hearing_margin
from collavn.models.policy import ActorCritic, AgentTower
from collavn.training.config import PPOConfig
from collavn.training.rollout import Rollout


@dataclass(frozen=True)
class PPOStats:
    """Means over the mini-batches of the last update.

    Attributes:
        policy_loss: Clipped surrogate loss.
        value_loss: ``½ (V − R)²``.
        entropy: Policy entropy.
        approx_kl: ``E[(r − 1) − log r]`` (Schulman's estimator).
        clip_fraction: Fraction of ratios outside ``[1 − ε, 1 + ε]``.
        loss: The total optimised loss.
        epochs: Epochs run (fewer than ``update_epochs`` when ``target_kl`` stopped them).
        bc_loss: Negative log-likelihood of the behaviour-cloning targets (the
            expert's actions, or the ``--init-from`` policy's with ``--ppo.bc-target
            init``; 0 without ``--ppo.bc-coef``).
        bc_weight: The weight it had in ``loss``.
        message_floor_loss: The message floor's term before its weight (0 without
            ``--ppo.message-floor``, or while every floor step hears a teammate).
        grad_norm: Norm of the whole gradient before clipping.
        comm_grad_norm: Norm of the communication parameters' part of it (0 without
            messages): how hard the losses pull on what is sent and when gates open.
    """

    policy_loss: float
    value_loss: float
    entropy: float
    approx_kl: float
    clip_fraction: float
    loss: float
    epochs: float
    grad_norm: float = 0.0
    comm_grad_norm: float = 0.0
    bc_loss: float = 0.0
    bc_weight: float = 0.0
    message_floor_loss: float = 0.0


def masked_mean(x: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``x`` over the entries where ``mask`` is true (0 if none).

    A non-negative float ``mask`` weighs the entries: the weighted mean.
    """
    m = mask.to(x.dtype)
    return (x * m).sum() / m.sum().clamp(min=torch.finfo(x.dtype).tiny)


def explained_variance(values: Tensor, returns: Tensor, mask: Tensor) -> float:
    """How much of the returns the critic explains: ``1 − Var(R − V) / Var(R)``, masked.

    1 when ``V = R``, 0 when ``V`` does no better than the returns' mean, below 0 when
    worse. ``nan`` when the masked returns do not vary (nothing to explain).
    """
    m = mask.bool()
    r = returns[m].double()
    if r.numel() < 2:
        return math.nan
    var = float(r.var(unbiased=False))
    if var == 0.0:
        return math.nan
    return 1.0 - float((r - values[m].double()).var(unbiased=False)) / var


def message_floor_loss(margin: Tensor, mask: Tensor, floor: float, width: float) -> Tensor:
    """``mean relu(width − margin)`` over the ⌈floor·n⌉ largest of the ``n`` masked margins.

    ``margin`` from :func:`~collavn.models.communication.hearing_margin` (> 0: a message
    arrives). Zero when at least that many margins reach ``width``, or none is masked.
    """
    m = margin[mask]
    if floor <= 0 or m.numel() == 0:
        return margin.new_zeros(())
    k = max(1, math.ceil(floor * m.numel()))
    return torch.relu(width - m.topk(k).values).mean()


def ppo_loss(model: ActorCritic, batch: Rollout, advantages: Tensor, returns: Tensor,
             cfg: PPOConfig, critic_only: bool = False,
             bc_weight: float = 0.0) -> tuple[Tensor, dict[str, float]]:
    """The PPO loss of one mini-batch of sequences ``(T, E_b, N)`` and its statistics.

    ``critic_only``: the optimised loss is the value term alone (statistics as usual).
    ``bc_weight`` > 0 adds ``bc_weight × −log π(a* | s)`` over active steps, ``a*`` the
    targets stored in ``batch.expert_actions`` (the expert's actions or the anchor's),
    each step's term times ``batch.weights`` when the rollout has them
    (``--ppo.bc-steps sighted``: 1 once the goal was in sight, else 0; ``blocked``: 1
    shortly after a collision, else 0).
    ``cfg.message_floor`` > 0 adds ``cfg.message_floor_coef ×``
    :func:`message_floor_loss` of the communication scores (not while ``critic_only``).
    """
    if bc_weight > 0 and batch.expert_actions is None:
        raise ValueError("a behaviour-cloning weight needs a rollout with expert_actions "
                         "(collected with --ppo.bc-coef > 0)")
    floor = cfg.message_floor > 0 and not critic_only
    out = model.evaluate_actions(batch.obs, batch.initial_state, batch.episode_start,
                                 batch.raw_actions, batch.percepts,
                                 batch.expert_actions if bc_weight > 0 else None,
                                 scores=floor)
    mask = batch.active
    adv = advantages
    if cfg.norm_adv:
        mean = masked_mean(adv, mask)
        std = masked_mean((adv - mean) ** 2, mask).sqrt()
        adv = (adv - mean) / (std + 1e-8)
    log_ratio = out.log_prob - batch.log_probs
    ratio = log_ratio.exp()
    surrogate = torch.max(-adv * ratio,
                          -adv * ratio.clamp(1.0 - cfg.clip_coef, 1.0 + cfg.clip_coef))
    policy_loss = masked_mean(surrogate, mask)
    value_loss = 0.5 * masked_mean((out.value - returns) ** 2, mask)
    entropy = masked_mean(out.entropy, mask)
    bc_loss = torch.zeros(())
    if out.target_log_prob is not None:  # a mean over active steps, weighted per step
        weights = 1.0 if batch.weights is None else batch.weights
        bc_loss = -masked_mean(out.target_log_prob * weights, mask)
    floor_loss = torch.zeros(())
    if floor:
        assert out.scores is not None
        comm = model.cfg.comm
        margin, hears = hearing_margin(out.scores, mask, comm)
        floor_loss = message_floor_loss(margin, hears, cfg.message_floor, comm.temperature)
    loss = (cfg.vf_coef * value_loss if critic_only
            else policy_loss + cfg.vf_coef * value_loss - cfg.ent_coef * entropy
            + bc_weight * bc_loss + cfg.message_floor_coef * floor_loss)
    with torch.no_grad():
        parts = {"policy_loss": policy_loss, "value_loss": value_loss, "entropy": entropy,
                 "bc_loss": bc_loss, "bc_weight": torch.tensor(bc_weight),
                 "message_floor_loss": floor_loss,
                 "loss": loss, "approx_kl": masked_mean((ratio - 1) - log_ratio, mask),
                 "clip_fraction": masked_mean(((ratio - 1).abs() > cfg.clip_coef).float(),
                                              mask)}
        stats = {k: float(v.detach()) for k, v in parts.items()}
    return loss, stats


def critic_parameters(model: ActorCritic) -> list[torch.nn.Parameter]:
    """The parameters only the critic uses: its GRU core and value head, every tower."""
    params: list[torch.nn.Parameter] = []
    for tower in model.towers:
        assert isinstance(tower, AgentTower)
        params += [*tower.critic_core.parameters(), *tower.critic_value.parameters()]
    return params


def comm_parameters(model: ActorCritic) -> list[torch.nn.Parameter]:
    """The communication module's weights (F_query, F_key, F_value, ψ), every tower."""
    params: list[torch.nn.Parameter] = []
    for tower in model.towers:
        assert isinstance(tower, AgentTower)
        if tower.comm is not None:
            params += [p for p in tower.comm.parameters() if p.requires_grad]
    return params


def grad_norm(params: list[torch.nn.Parameter]) -> float:
    """The 2-norm of the gradients of ``params`` (those without one count as zero)."""
    norms = [p.grad.detach().norm() for p in params if p.grad is not None]
    return float(torch.stack(norms).norm()) if norms else 0.0


def minibatch_envs(num_envs: int, num_minibatches: int,
                   generator: torch.Generator) -> list[Tensor]:
    """A random split of env indices into ``min(num_minibatches, num_envs)`` groups."""
    order = torch.randperm(num_envs, generator=generator)
    return [part for part in torch.tensor_split(order, min(num_minibatches, num_envs))
            if len(part)]


def ppo_update(model: ActorCritic, optimizer: torch.optim.Optimizer, rollout: Rollout,
               advantages: Tensor, returns: Tensor, cfg: PPOConfig, generator: torch.Generator,
               sync_gradients: Callable[[], None] | None = None,
               critic_only: bool = False, bc_weight: float = 0.0) -> PPOStats:
    """``update_epochs`` passes of ``num_minibatches`` gradient steps over one rollout.

    Args:
        model: The actor-critic (in ``train()`` mode).
        optimizer: Over the policy parameters.
        rollout: The collected rollout.
        advantages: ``(T, E, N)`` from :func:`~collavn.training.rollout.compute_gae`.
        returns: ``(T, E, N)`` value targets.
        cfg: PPO settings.
        generator: Shuffles the mini-batches (seeded: runs are reproducible).
        sync_gradients: Called between ``backward`` and the optimizer step (distributed
            runs average gradients over processes here).
        critic_only: Optimise the value loss and step only the critic's own parameters
            (:func:`critic_parameters`); everything else keeps its weights and its
            optimizer state.
        bc_weight: Weight of the behaviour-cloning term (see :func:`ppo_loss`).
    """
    params = [p for group in optimizer.param_groups for p in group["params"]]
    critic = {id(p) for p in critic_parameters(model)}
    comm = comm_parameters(model)
    totals: dict[str, float] = {}
    count = epochs = 0
    for _ in range(cfg.update_epochs):
        epochs += 1
        epoch_kl: list[float] = []
        for index in minibatch_envs(rollout.rewards.shape[1], cfg.num_minibatches, generator):
            loss, stats = ppo_loss(model, rollout.select_envs(index), advantages[:, index],
                                   returns[:, index], cfg, critic_only, bc_weight)
            optimizer.zero_grad(set_to_none=False)
            loss.backward()
            if sync_gradients is not None:
                sync_gradients()
            if critic_only:  # Adam skips parameters without a gradient
                for p in params:
                    if id(p) not in critic:
                        p.grad = None
            stats["comm_grad_norm"] = grad_norm(comm)
            stats["grad_norm"] = float(torch.nn.utils.clip_grad_norm_(params,
                                                                      cfg.max_grad_norm))
            optimizer.step()
            for k, v in stats.items():
                totals[k] = totals.get(k, 0.0) + v
            count += 1
            epoch_kl.append(stats["approx_kl"])
        if cfg.target_kl > 0 and not critic_only and float(np.mean(epoch_kl)) > cfg.target_kl:
            break  # the policy moved far enough from the one that collected the rollout
    return PPOStats(**{k: v / max(count, 1) for k, v in totals.items()}, epochs=epochs)
