"""Method ``il``: one agent imitates a privileged expert; copies of it act at test.

The learner has no communication (``CommConfig.variant = "none"``) and shared weights,
so it *is* a single-agent policy; during training every agent of an env runs a copy of
it and each copy is supervised by the expert's action towards its own goal (the other
agents are just moving obstacles, as at test time).

Behaviour cloning: the expert drives (β = 1) and the policy maximises the likelihood of
the expert's action under its Gaussian — mean *and* learned standard deviation
(``log_std``) — over active agent-steps, through the recurrent core over whole
sequences. Mean squared error on the mean alone fixes σ, so the sampled policy stays as
noisy as at initialisation while its mean, never asked to carry the action on its own,
averages the expert into timid or wall-pushing moves; with the likelihood, σ shrinks to
the residual error, the loss weighs the mean's errors by 1/σ², and the mean action is the
policy to deploy. DAgger: the learner drives with probability ``1 − β`` per env and
step, β decaying per update, and is still supervised by the expert's action in the
states it visits. The rollout stores the expert's actions in ``Rollout.raw_actions``
and, like PPO's, the stored percepts (a frozen encoder is never re-run by the update;
the DAgger buffer keeps the map predictions made at collection).

The expert (``--imitation.expert``) is the oracle by default, as in the paper's
baseline. ``seeker`` instead explores like the goal-blind explorer until the goal is in
sight and follows the oracle from then on (:mod:`collavn.policies.seeker`): a teacher
whose every move is a function of what the learner can sense, so that where the learner
cannot tell where the goal is, the target it averages is a deliberate search rather
than the mean of left and right turns.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch
from torch import Tensor

from collavn.errors import CollavnError
from collavn.models.belief import belief_loss, sector_accuracy
from collavn.models.policy import ActorCritic
from collavn.policies.oracle import OraclePolicy
from collavn.policies.seeker import SeekerPolicy, SeekerState
from collavn.scenes.scene import Scene
from collavn.training.config import ImitationConfig
from collavn.training.ppo import masked_mean, minibatch_envs
from collavn.training.rollout import Rollout


def expert_probability(cfg: ImitationConfig, iteration: int) -> float:
    """β: the probability that the expert drives at update ``iteration``."""
    if not cfg.dagger:
        return 1.0
    return max(cfg.beta_min, cfg.beta_decay ** iteration)


class Expert:
    """The privileged teacher of ``il`` (``--imitation.expert``) and its memory.

    Args:
        cfg: Which expert, and the seeker's sight.
        scenes: The env's scenes.
        num_envs, num_agents: The env's shape (the seeker keeps per-agent memory).
        seed: Seeds the seeker's tie-breaking.
    """

    def __init__(self, cfg: ImitationConfig, scenes: Sequence[Scene], num_envs: int,
                 num_agents: int, seed: int = 0) -> None:
        self.policy: OraclePolicy | SeekerPolicy = (
            SeekerPolicy(list(scenes), cfg.sight, seed=seed) if cfg.expert == "seeker"
            else OraclePolicy(scenes))
        self.state: SeekerState | None = (
            self.policy.initial_state(num_envs, num_agents)
            if isinstance(self.policy, SeekerPolicy) else None)

    def act(self, obs: dict[str, np.ndarray]) -> np.ndarray:
        """The expert's ``(E, N, 2)`` actions; an env where the oracle fails gets zeros.

        The oracle plans on the navigation grid; a pose it cannot plan from (e.g. pushed
        off the grid's connected region by a collision) must not stop a training run.
        (The seeker explores from such a pose instead.)
        """
        if isinstance(self.policy, OraclePolicy):
            return oracle_actions(self.policy, obs)
        assert self.state is not None
        actions, self.state = self.policy.act(obs, self.state)
        return actions

    def homing(self) -> np.ndarray | None:
        """Which agents the seeker is homing: ``(E, N)`` bool, ``None`` for the oracle.

        An agent homes (follows the oracle) once its goal has been in sight this
        episode, as of the seeker's last :meth:`act`.
        """
        return None if self.state is None else self.state.seen.copy()

    def executed(self, actions: np.ndarray, active: np.ndarray) -> None:
        """Tell the expert what the env was given (DAgger: often the learner's actions)."""
        if isinstance(self.policy, SeekerPolicy):
            assert self.state is not None
            self.policy.executed(self.state, actions, active)


def oracle_actions(oracle: OraclePolicy, obs: dict[str, np.ndarray]) -> np.ndarray:
    """The oracle's ``(E, N, 2)`` actions, zeros (stand still) for an env where it fails."""
    try:
        return oracle.act(obs, None)[0]
    except CollavnError:
        out = np.zeros((*obs["active"].shape, 2))
        for e in range(out.shape[0]):
            one = {k: v[e:e + 1] for k, v in obs.items()}
            try:
                out[e] = oracle.act(one, None)[0][0]
            except CollavnError:
                pass
        return out


def mix_actions(learner: np.ndarray, expert: np.ndarray, beta: float,
                rng: np.random.Generator) -> np.ndarray:
    """Per env, the expert's ``(N, 2)`` actions with probability β, else the learner's."""
    use_expert = np.asarray(rng.random(learner.shape[0]) < beta)
    return np.where(use_expert[:, None, None], expert, learner)


def imitation_loss(model: ActorCritic, batch: Rollout, belief_coef: float = 0.0,
                   stats: dict[str, list[float]] | None = None) -> Tensor:
    """Negative log-likelihood of the expert's actions, mean over active ``(T, E, N)``.

    ``-log N(a* | μ(s), σ)`` with the policy's own mean and learned state-independent σ;
    a weighted mean when the rollout carries ``weights`` (``--imitation.homing-weight``).
    With a goal-belief head (``ModelConfig.goal_belief``) and the rollout's labels, plus
    ``belief_coef ×`` (the sector's cross-entropy + the log distance's squared error).
    ``stats`` collects each term (and the belief's sector accuracy, ±1 sector).
    """
    out = model.evaluate_actions(batch.obs, batch.initial_state, batch.episode_start,
                                 batch.raw_actions, batch.percepts)
    mask = batch.active if batch.weights is None else batch.weights * batch.active
    loss = -masked_mean(out.log_prob, mask)
    record = {"imitation": float(loss.detach())}
    if out.belief is not None and batch.belief_labels is not None and belief_coef > 0:
        sector, distance = belief_loss(out.belief, batch.belief_labels, batch.active)
        loss = loss + belief_coef * (sector + distance)
        record |= {"belief_sector": float(sector.detach()),
                   "belief_distance": float(distance.detach()),
                   "belief_accuracy": sector_accuracy(out.belief.detach(),
                                                      batch.belief_labels, batch.active)}
    if stats is not None:
        for k, v in record.items():
            stats.setdefault(k, []).append(v)
    return loss


def imitation_update(model: ActorCritic, optimizer: torch.optim.Optimizer,
                     rollouts: Sequence[Rollout], cfg: ImitationConfig,
                     generator: torch.Generator, max_grad_norm: float,
                     sync_gradients: Callable[[], None] | None = None) -> dict[str, float]:
    """``epochs`` passes over the kept rollouts (shuffled), ``num_minibatches`` steps each.

    Returns:
        The mean of each loss term over the steps: ``imitation`` (the likelihood's) and,
        with a goal-belief head, ``belief_sector``, ``belief_distance`` and
        ``belief_accuracy``.
    """
    params = [p for group in optimizer.param_groups for p in group["params"]]
    stats: dict[str, list[float]] = {}
    for _ in range(cfg.epochs):
        for k in torch.randperm(len(rollouts), generator=generator).tolist():
            _rollout_steps(model, optimizer, params, rollouts[k], cfg, generator,
                           max_grad_norm, sync_gradients, stats)
    return {k: float(np.nanmean(v)) for k, v in stats.items()}


def _rollout_steps(model: ActorCritic, optimizer: torch.optim.Optimizer,
                   params: list[torch.nn.Parameter], rollout: Rollout, cfg: ImitationConfig,
                   generator: torch.Generator, max_grad_norm: float,
                   sync_gradients: Callable[[], None] | None,
                   stats: dict[str, list[float]]) -> None:
    for index in minibatch_envs(rollout.rewards.shape[1], cfg.num_minibatches, generator):
        loss = imitation_loss(model, rollout.select_envs(index), cfg.belief_coef, stats)
        optimizer.zero_grad(set_to_none=False)
        loss.backward()
        if sync_gradients is not None:
            sync_gradients()
        torch.nn.utils.clip_grad_norm_(params, max_grad_norm)
        optimizer.step()
