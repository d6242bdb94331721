"""PPO's message floor (``--ppo.message-floor``): keep a share of agent-steps hearing."""

from __future__ import annotations

import dataclasses

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from collavn.errors import ConfigError
from collavn.models.communication import (
    communication_counts,
    hearing_margin,
    match_and_select,
)
from collavn.models.config import CommConfig
from collavn.training.config import PPOConfig
from collavn.training.distributed import DistInfo
from collavn.training.ppo import message_floor_loss, ppo_loss, ppo_update
from collavn.training.rollout import compute_gae
from collavn.training.trainer import build_run, collect_rollout, learn, sync_point
from training_fixtures import tiny_config

CFG = CommConfig(query_dim=4, key_dim=2, value_dim=3, temperature=0.05)


@settings(max_examples=40, deadline=None)
@given(st.integers(1, 4), st.integers(0, 10_000))
def test_hearing_margin_is_positive_exactly_when_a_teammates_value_arrives(n, seed):
    g = torch.Generator().manual_seed(seed)
    e, slots = 6, 2
    active = torch.rand(e, n, generator=g) < 0.8
    mask = torch.ones(e, n, slots, dtype=torch.bool)
    query, bias = torch.randn(e, n, 2, generator=g) * 2, torch.randn(e, n, generator=g)
    keys, values = (torch.randn(e, n, slots, 2, generator=g),
                    torch.rand(e, n, slots, 3, generator=g))
    msg = match_and_select(query, bias, keys, values, mask, active, CFG)
    margin, hears = hearing_margin(msg.scores, active, CFG)
    received = communication_counts(msg, active).received
    assert torch.equal(hears, active & (active.sum(dim=1, keepdim=True) >= 2))
    assert torch.equal((margin > 0) & hears, received)
    assert torch.isfinite(margin).all()
    # a (T, E, N, N) stack gives the same per step
    stacked, _ = hearing_margin(msg.scores[None].expand(3, -1, -1, -1), active[None].expand(
        3, -1, -1), CFG)
    assert torch.equal(stacked[1], margin)


def test_hearing_margin_by_hand_and_its_gradient_reaches_the_deciding_scores():
    scores = torch.tensor([[[0.7, 0.6, 0.2],    # agent 0: own 0.7, best teammate 0.6
                            [0.9, 0.4, 0.1],    # agent 1: own 0.4 decides
                            [0.8, 0.3, 0.9]]],  # agent 2: inactive
                          requires_grad=True)
    active = torch.tensor([[True, True, False]])
    margin, hears = hearing_margin(scores, active, CFG)  # η = 1/2 with two active
    assert torch.equal(hears, torch.tensor([[True, True, False]]))
    assert margin[0, :2].tolist() == pytest.approx([0.1, -0.1])
    margin[0, :2].sum().backward()
    assert scores.grad is not None
    expected = torch.zeros(1, 3, 3)
    expected[0, 0, 1] = 1.0  # min(0.7, 0.6): the link to agent 1
    expected[0, 1, 1] = 1.0  # min(0.4, 0.9): agent 1's own gate
    assert torch.equal(scores.grad, expected)


def test_floor_loss_pushes_only_the_top_share_and_is_zero_once_they_pass():
    margin = torch.tensor([-0.4, -0.3, 0.01, -0.2, 0.2, 0.0], requires_grad=True)
    mask = torch.tensor([True, True, True, False, True, True])
    # 5 masked margins, floor 0.5: the top ⌈2.5⌉ = 3 are 0.2, 0.01, 0.0
    loss = message_floor_loss(margin, mask, 0.5, 0.05)
    assert float(loss.detach()) == pytest.approx((0.0 + 0.04 + 0.05) / 3)
    loss.backward()
    assert margin.grad is not None
    assert margin.grad.tolist() == pytest.approx([0, 0, -1 / 3, 0, 0, -1 / 3])
    with torch.no_grad():
        assert float(message_floor_loss(margin, mask, 0.2, 0.05)) == 0.0  # 0.2 ≥ τ
        assert float(message_floor_loss(margin, mask, 0.0, 0.05)) == 0.0
        none = torch.zeros(6, dtype=torch.bool)
        assert float(message_floor_loss(margin, none, 1.0, 0.05)) == 0.0


def _floor_run(floor: float, coef: float = 1.0):
    cfg = tiny_config(method="ours", rollout_steps=8)
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(
        cfg.ppo, message_floor=floor, message_floor_coef=coef))
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    return cfg, run


def _heard(run, rollout) -> float:
    with torch.no_grad():
        out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                         rollout.episode_start, rollout.raw_actions,
                                         rollout.percepts, scores=True)
    assert out.scores is not None
    margin, hears = hearing_margin(out.scores, rollout.active, run.model.cfg.comm)
    return float((margin[hears] > 0).float().mean())


def test_the_floor_is_a_term_of_ppos_loss_and_reopens_shut_gates():
    cfg, run = _floor_run(1.0)
    rollout, _ = collect_rollout(run)
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    # shut every gate: ψ's bias far below, as PPO's drift leaves them
    biases = [t.comm.psi_bias for t in run.model.towers if t.comm is not None]
    with torch.no_grad():
        for b in biases:
            b.fill_(-6.0)
    assert _heard(run, rollout) == 0.0
    plain_cfg = dataclasses.replace(cfg.ppo, message_floor=0.0)
    plain, plain_stats = ppo_loss(run.model, rollout, adv, ret, plain_cfg)
    floored, stats = ppo_loss(run.model, rollout, adv, ret, cfg.ppo)
    assert plain_stats["message_floor_loss"] == 0.0
    assert stats["message_floor_loss"] > 0.3  # every margin ≈ σ(−6) − ½
    assert float((floored - plain).detach()) == pytest.approx(stats["message_floor_loss"],
                                                              rel=1e-4)
    # critic warm-up optimises the value loss alone: no floor there
    _, warm_stats = ppo_loss(run.model, rollout, adv, ret, cfg.ppo, critic_only=True)
    assert warm_stats["message_floor_loss"] == 0.0

    start = {k: v.clone() for k, v in run.model.state_dict().items()}
    opt_start = run.optimizer.state_dict()
    heard = {}
    for floor in (0.0, 1.0):  # the same updates from the same weights, without and with
        run.model.load_state_dict(start)
        run.optimizer.load_state_dict(opt_start)
        for group in run.optimizer.param_groups:
            group["lr"] = 3e-2
        ppo = dataclasses.replace(cfg.ppo, message_floor=floor, update_epochs=30,
                                  num_minibatches=1)
        ppo_update(run.model, run.optimizer, rollout, adv, ret, ppo,
                   torch.Generator().manual_seed(0))
        heard[floor] = _heard(run, rollout)
    assert heard[0.0] == 0.0 and heard[1.0] > 0.5, heard


def test_learn_logs_the_floor_term():
    _, run = _floor_run(0.5)
    rollout, _ = collect_rollout(run)
    losses = learn(run, rollout)
    assert "loss/message_floor_loss" in losses
    assert losses["loss/message_floor_loss"] >= 0.0


@pytest.mark.parametrize("field,value", [("message_floor", -0.1), ("message_floor", 1.5),
                                         ("message_floor", float("nan")),
                                         ("message_floor_coef", -1.0)])
def test_bad_floor_settings_are_refused(field, value):
    with pytest.raises(ConfigError, match=rf"--ppo\.{field.replace('_', '-')}"):
        PPOConfig(**{field: value})


@pytest.mark.parametrize("method", ["no-com", "il"])
def test_a_method_that_sends_nothing_refuses_the_floor(method):
    cfg = tiny_config(method="ours")
    with pytest.raises(ConfigError, match=r"message-floor.*sends none"):
        dataclasses.replace(cfg, method=method,
                            ppo=dataclasses.replace(cfg.ppo, message_floor=0.3))


def test_a_no_listen_run_is_deaf_in_collection_and_in_the_update():
    """``--model.comm.no-listen``: nothing heard while collecting, and PPO's replay of
    the rollout is deaf too (its log-probs are the collected ones; hearing changes them)."""
    run, rollout, stats = _open_gates_run(listen=False)
    assert not run.model.listen
    assert stats["comm/received_rate"] == 0.0 and stats["comm/when_rate"] > 0.0
    assert torch.allclose(_replay(run, rollout).log_prob, rollout.log_probs, atol=1e-5)
    run.model.listen = True
    assert not torch.allclose(_replay(run, rollout).log_prob, rollout.log_probs, atol=1e-3)


def _open_gates_run(**comm):
    """A tiny ``ours`` run with these ``CommConfig`` fields, every gate wide open (ψ's
    bias far above η: a teammate's entry reaches every linked agent), and one rollout."""
    cfg = tiny_config(method="ours", rollout_steps=8)
    cfg = dataclasses.replace(cfg, model=dataclasses.replace(
        cfg.model, comm=dataclasses.replace(cfg.model.comm, **comm)))
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    with torch.no_grad():
        for tower in run.model.towers:
            tower.comm.psi_bias.fill_(6.0)
    rollout, stats = collect_rollout(run)
    return run, rollout, stats


def _replay(run, rollout):
    """PPO's replay of the rollout's stored inputs (log-probs and values), no gradient."""
    with torch.no_grad():
        return run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                          rollout.episode_start, rollout.raw_actions,
                                          rollout.percepts)


@pytest.mark.parametrize("half", ["critic_hears", "actor_hears"])
def test_a_half_hearing_run_replays_its_collection_and_only_one_half_hears(half):
    """``--model.comm.no-critic-hears`` / ``no-actor-hears``: PPO's replay gives the
    collected log-probs and values; cutting every link leaves the deaf half as it is and
    changes the half that hears."""
    run, rollout, stats = _open_gates_run(**{half: False})
    assert stats["comm/received_rate"] > 0.0
    heard = _replay(run, rollout)
    assert torch.allclose(heard.log_prob, rollout.log_probs, atol=1e-5)
    assert torch.allclose(heard.value, rollout.values, atol=1e-5)
    run.model.listen = False
    deaf = _replay(run, rollout)
    actor_deaf = half == "actor_hears"
    assert torch.allclose(deaf.log_prob, heard.log_prob, atol=1e-5) == actor_deaf
    assert torch.allclose(deaf.value, heard.value, atol=1e-5) != actor_deaf
