"""PPO's behaviour-cloning term (``--ppo.bc-coef``): the expert runs beside the policy."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from collavn.errors import ConfigError
from collavn.policies.seeker import SeekerPolicy
from collavn.training.config import ImitationConfig, PPOConfig
from collavn.training.distributed import DistInfo
from collavn.training.ppo import ppo_loss, ppo_update
from collavn.training.rollout import compute_gae
from collavn.training.trainer import build_run, collect_rollout, env_config, learn, sync_point
from training_fixtures import tiny_config


def _bc_run(method: str = "no-com", bc_coef: float = 1.0, rollout_steps: int = 6):
    cfg = tiny_config(method=method, rollout_steps=rollout_steps,
                      imitation=ImitationConfig(expert="seeker"))
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, bc_coef=bc_coef))
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    return cfg, run


def test_plain_ppo_has_no_expert_and_no_privileged_observations():
    cfg = tiny_config(method="no-com", imitation=ImitationConfig(expert="seeker"))
    assert not env_config(cfg).privileged and not env_config(cfg).depth
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    assert run.expert is None
    rollout, _ = collect_rollout(run)
    assert rollout.expert_actions is None
    assert rollout.select_envs(torch.tensor([0])).expert_actions is None


def test_bc_rollout_stores_the_experts_actions_beside_the_policys_own():
    cfg, run = _bc_run()
    assert env_config(cfg).privileged and env_config(cfg).depth
    assert run.expert is not None and isinstance(run.expert.policy, SeekerPolicy)
    twin = SeekerPolicy(list(run.env.scenes), cfg.imitation.sight, seed=cfg.run.seed)
    first, _ = twin.act(run.obs, twin.initial_state(run.env.num_envs, run.env.num_agents))
    rollout, collected = collect_rollout(run)
    assert rollout.expert_actions is not None
    np.testing.assert_allclose(rollout.expert_actions[0].numpy(), first, atol=1e-6)
    # PPO drives: the stored actions are the policy's samples, scored when collected
    assert not torch.allclose(rollout.raw_actions, rollout.expert_actions)
    assert "imitation/beta" not in collected
    part = rollout.select_envs(torch.tensor([1]))
    assert part.expert_actions is not None
    assert torch.equal(part.expert_actions, rollout.expert_actions[:, [1]])


def test_bc_term_is_the_experts_negative_log_likelihood_and_pulls_the_mean_to_it():
    cfg, run = _bc_run(rollout_steps=8)
    rollout, _ = collect_rollout(run)
    assert rollout.expert_actions is not None
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    plain, plain_stats = ppo_loss(run.model, rollout, adv, ret, cfg.ppo)
    weighted, stats = ppo_loss(run.model, rollout, adv, ret, cfg.ppo, bc_weight=2.0)
    with torch.no_grad():
        out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                         rollout.episode_start, rollout.raw_actions,
                                         rollout.percepts, rollout.expert_actions)
    assert out.target_log_prob is not None
    # only the means learn from the expert: σ stays PPO's (fitted to the expert on the
    # states a noisy policy visits, it widened and the mean action lost its way)
    replay = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                        rollout.episode_start, rollout.raw_actions,
                                        rollout.percepts, rollout.expert_actions)
    assert replay.target_log_prob is not None
    run.model.zero_grad(set_to_none=True)
    replay.target_log_prob.sum().backward()
    log_std = [p for n, p in run.model.named_parameters() if n.endswith("log_std")]
    assert log_std and all(p.grad is None or not p.grad.any() for p in log_std)
    assert any(p.grad is not None and p.grad.any() for p in run.model.parameters())
    run.model.zero_grad(set_to_none=True)
    active = rollout.active
    nll = -float(out.target_log_prob[active].mean())
    assert stats["bc_loss"] == pytest.approx(nll, rel=1e-5)
    assert plain_stats["bc_loss"] == 0.0
    assert float((weighted - plain).detach()) == pytest.approx(2.0 * nll, rel=1e-4)

    ppo = dataclasses.replace(cfg.ppo, update_epochs=20, num_minibatches=1)
    for group in run.optimizer.param_groups:
        group["lr"] = 3e-3
    start = {k: v.clone() for k, v in run.model.state_dict().items()}
    opt_start = run.optimizer.state_dict()
    after = {}
    for weight in (0.0, 5.0):  # the same update from the same weights, without and with BC
        run.model.load_state_dict(start)
        run.optimizer.load_state_dict(opt_start)
        ppo_update(run.model, run.optimizer, rollout, adv, ret, ppo,
                   torch.Generator().manual_seed(0), bc_weight=weight)
        after[weight] = ppo_loss(run.model, rollout, adv, ret, cfg.ppo, bc_weight=1.0)[1]
    assert after[5.0]["bc_loss"] < stats["bc_loss"] - 0.5, (stats, after)
    assert after[5.0]["bc_loss"] < after[0.0]["bc_loss"] - 0.5, after


def test_learn_weighs_bc_by_its_decay_and_a_rollout_without_targets_is_refused():
    cfg, run = _bc_run(method="ours")
    run.cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, bc_decay=0.5))
    rollout, _ = collect_rollout(run)
    run.iteration = 3
    losses = learn(run, rollout)
    assert losses["loss/bc_weight"] == pytest.approx(0.125)
    assert losses["loss/bc_loss"] > 0
    rollout.expert_actions = None
    adv = torch.zeros_like(rollout.rewards)
    with pytest.raises(ValueError, match="expert_actions"):
        ppo_loss(run.model, rollout, adv, adv, cfg.ppo, bc_weight=1.0)


@pytest.mark.parametrize("field,value", [("bc_coef", -1.0), ("bc_coef", float("nan")),
                                         ("bc_decay", 0.0), ("bc_decay", 1.5)])
def test_bad_bc_settings_are_refused(field, value):
    with pytest.raises(ConfigError, match=rf"--ppo\.{field.replace('_', '-')}"):
        PPOConfig(**{field: value})


def test_start_std_sets_sigma_after_init_from_and_zero_keeps_the_checkpoints(tmp_path):
    from collavn.training.trainer import train

    il = tiny_config(method="il", out=str(tmp_path / "il")).with_run(total_steps=16)
    train(il)
    cfg = tiny_config(method="no-com", out=str(tmp_path / "ft")).with_run(
        init_from=str(tmp_path / "il" / "checkpoint.pt"), total_steps=16)
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, start_std=0.1))
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    assert torch.allclose(run.model.towers[0].log_std, torch.full((2,), np.log(0.1)))
    kept = build_run(dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, start_std=0.0)),
                     DistInfo(), torch.device("cpu"))
    assert not torch.allclose(kept.model.towers[0].log_std, run.model.towers[0].log_std)
    with pytest.raises(ConfigError, match=r"--ppo\.start-std"):
        PPOConfig(start_std=-0.1)


def _annealed(tmp_path, method: str = "no-com", total: int = 64):
    cfg = tiny_config(method=method, out=str(tmp_path / "anneal")).with_run(total_steps=total)
    return dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, start_std=0.4,
                                                             end_std=0.05))


def test_end_std_schedule_is_log_linear_from_start_to_end(tmp_path):
    from collavn.training.trainer import annealed_std

    cfg = _annealed(tmp_path, total=1000)
    assert annealed_std(cfg, 0) == pytest.approx(0.4)
    assert annealed_std(cfg, 500) == pytest.approx(np.sqrt(0.4 * 0.05))
    assert annealed_std(cfg, 1000) == pytest.approx(0.05)
    assert annealed_std(cfg, 5000) == pytest.approx(0.05)  # past the end: stays there
    assert annealed_std(cfg, 250) > annealed_std(cfg, 750)


def test_end_std_sets_sigma_before_each_rollout_and_ppo_does_not_train_it(tmp_path):
    from collavn.training.trainer import anneal_std, annealed_std

    cfg = _annealed(tmp_path)
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    log_std = run.model.towers[0].log_std
    assert not log_std.requires_grad
    assert all(p is not log_std for g in run.optimizer.param_groups for p in g["params"])
    sync_point(run)
    seen = []
    for _ in range(3):
        anneal_std(run)
        expected = np.log(annealed_std(cfg, run.agent_steps))
        assert torch.allclose(log_std, torch.full((2,), expected, dtype=log_std.dtype))
        rollout, _ = collect_rollout(run)
        losses = learn(run, rollout)
        assert losses["opt/action_std"] == pytest.approx(float(np.exp(expected)), rel=1e-5)
        # learning moved the other weights, not σ
        assert torch.allclose(log_std, torch.full((2,), expected, dtype=log_std.dtype))
        seen.append(float(np.exp(expected)))
        run.agent_steps += run.steps_per_update
    assert seen[0] == pytest.approx(0.4) and seen[0] > seen[1] > seen[2]


def test_end_std_run_ends_on_the_schedule_and_bad_settings_are_refused(tmp_path):
    from collavn.training.trainer import annealed_std, restore, train

    cfg = _annealed(tmp_path, total=32)
    result = train(cfg)
    run = build_run(cfg.with_run(out=str(tmp_path / "other")), DistInfo(), torch.device("cpu"))
    restore(run, tmp_path / "anneal" / "checkpoint.pt")
    last_rollout = result.agent_steps - run.steps_per_update
    assert torch.allclose(run.model.towers[0].log_std.exp(),
                          torch.full((2,), annealed_std(cfg, last_rollout)))
    with pytest.raises(ConfigError, match=r"--ppo\.end-std.*--ppo\.start-std"):
        PPOConfig(end_std=0.05)
    with pytest.raises(ConfigError, match=r"--ppo\.end-std"):
        PPOConfig(start_std=0.1, end_std=float("nan"))
    with pytest.raises(ConfigError, match=r"--ppo\.end-std.*'il'"):
        dataclasses.replace(tiny_config(method="il"), ppo=PPOConfig(start_std=0.2,
                                                                    end_std=0.05))
