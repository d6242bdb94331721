"""PPO's anchor (``--ppo.bc-target init``): behaviour cloning on the ``--init-from`` policy."""

from __future__ import annotations

import copy
import dataclasses
import math

import numpy as np
import pytest
import torch

from collavn.errors import ConfigError
from collavn.training.config import PPOConfig
from collavn.training.distributed import DistInfo
from collavn.training.trainer import (
    anchor_targets,
    build_run,
    collect_rollout,
    env_config,
    learn,
    sync_point,
    train,
)
from training_fixtures import tiny_config


@pytest.fixture(scope="module")
def il_checkpoint(tmp_path_factory):
    out = tmp_path_factory.mktemp("anchor") / "il"
    train(tiny_config(method="il", out=str(out)).with_run(total_steps=16))
    return out / "checkpoint.pt"


def _anchored(il_checkpoint, tmp_path, method: str = "ours", rollout_steps: int = 6):
    cfg = tiny_config(method=method, out=str(tmp_path / "ft"), rollout_steps=rollout_steps
                      ).with_run(init_from=str(il_checkpoint))
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(
        cfg.ppo, bc_coef=1.0, bc_target="init", start_std=0.1, lr=3e-3))
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    return cfg, run


def test_anchor_targets_are_the_init_policys_mean_actions_along_the_rollouts(
        il_checkpoint, tmp_path):
    cfg, run = _anchored(il_checkpoint, tmp_path)
    # no expert beside the policy, nothing privileged in the observations
    assert run.expert is None and not env_config(cfg).privileged
    assert run.anchor is not None and run.anchor is not run.model
    policy = copy.deepcopy(run.model)  # not updated below: it still is the anchor's policy
    for _ in range(2):  # the second rollout starts from the state the first one left
        rollout, _ = collect_rollout(run)
        assert rollout.expert_actions is not None and not rollout.expert_actions.any()
        anchor_targets(run, rollout)
        expected, _ = policy.mean_actions(rollout.obs, rollout.initial_state,
                                          rollout.episode_start, rollout.percepts)
        torch.testing.assert_close(rollout.expert_actions, expected, rtol=0, atol=1e-5)
        # the policy samples with σ = 0.1 around the same means: near, not equal
        active = rollout.active
        gap = (rollout.raw_actions - rollout.expert_actions)[active].abs()
        assert 0 < float(gap.mean()) < 0.5


def test_anchor_stays_frozen_while_ppo_moves_the_policy(il_checkpoint, tmp_path):
    _, run = _anchored(il_checkpoint, tmp_path, method="no-com")
    assert run.anchor is not None
    before = {k: v.clone() for k, v in run.anchor.state_dict().items()}
    policy_before = {k: v.clone() for k, v in run.model.state_dict().items()}
    assert not any(p.requires_grad for p in run.anchor.parameters())
    nll_at_target = 2 * (math.log(0.1) + 0.5 * math.log(2 * math.pi))
    for _ in range(2):
        rollout, _ = collect_rollout(run)
        losses = learn(run, rollout)
        run.iteration += 1
        # −log N(a*; μ, σ = 0.1) over 2 dims is smallest, 2 (log σ + ½ log 2π), at μ = a*:
        # the first update starts there (policy = anchor) and moves only a little away
        assert losses["loss/bc_weight"] == 1.0
        assert nll_at_target - 1e-4 <= losses["loss/bc_loss"] < nll_at_target + 0.5
    after = run.anchor.state_dict()
    assert all(torch.equal(before[k], after[k]) for k in before)
    assert any(not torch.equal(policy_before[k], v) for k, v in run.model.state_dict().items())


def test_anchor_needs_init_from_and_a_known_target(tmp_path):
    cfg = tiny_config(method="no-com", out=str(tmp_path / "x"))
    with pytest.raises(ConfigError, match="--init-from"):
        dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, bc_coef=0.5,
                                                         bc_target="init"))
    with pytest.raises(ConfigError, match=r"--ppo\.bc-target"):
        PPOConfig(bc_target="teacher")  # type: ignore[arg-type]
    # without a weight nothing is imitated, so no checkpoint is needed
    plain = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, bc_target="init"))
    assert build_run(plain, DistInfo(), torch.device("cpu")).anchor is None


def test_sighted_steps_weigh_the_anchor_only_once_the_goal_was_in_sight(
        il_checkpoint, tmp_path, monkeypatch):
    import collavn.training.trainer as trainer
    from collavn.policies.oracle import track_sighting
    from collavn.training.ppo import ppo_loss
    from collavn.training.rollout import compute_gae

    cfg = tiny_config(method="no-com", out=str(tmp_path / "ft"), rollout_steps=12
                      ).with_run(init_from=str(il_checkpoint))
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(
        cfg.ppo, bc_coef=1.0, bc_target="init", bc_steps="sighted"))
    assert env_config(cfg).privileged  # the trainer reads poses; the policy does not
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    flags = []

    def recorded(seen, obs, scenes, sight):
        assert sight == cfg.imitation.sight
        flags.append(track_sighting(seen, obs, scenes, sight))
        return flags[-1]

    monkeypatch.setattr(trainer, "track_sighting", recorded)
    # agent 0 of env 0 is shown a goal 50 m away at steps 0–2, its own position after
    step = run.env.step

    def place_goal(obs):
        far = len(flags) < 3
        obs["goal_position"][0, 0] = obs["world_pose"][0, 0, :2] + (50.0 if far else 0.0)
        return obs

    def stepped(actions):
        obs, *rest = step(actions)
        return (place_goal(obs), *rest)

    place_goal(run.obs)
    monkeypatch.setattr(run.env, "step", stepped)
    rollout, _ = collect_rollout(run)
    assert rollout.weights is not None and len(flags) == cfg.ppo.rollout_steps
    np.testing.assert_array_equal(rollout.weights.numpy(), np.stack(flags).astype(np.float32))
    assert bool(rollout.active[:4, 0, 0].all()) and not rollout.episode_start[1:4, 0, 0].any()
    assert rollout.weights[:4, 0, 0].tolist() == [0.0, 0.0, 0.0, 1.0]
    anchor_targets(run, rollout)
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    weighted = ppo_loss(run.model, rollout, adv, ret, cfg.ppo, bc_weight=1.0)[1]["bc_loss"]
    with torch.no_grad():
        out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                         rollout.episode_start, rollout.raw_actions,
                                         rollout.percepts, rollout.expert_actions)
    assert out.target_log_prob is not None
    active = rollout.active
    # a mean over every active step, searching ones adding 0
    expected = -float((out.target_log_prob * rollout.weights)[active].sum()) / int(active.sum())
    assert weighted == pytest.approx(expected, rel=1e-5)
    rollout.weights = None  # without weights: every step counts
    plain = ppo_loss(run.model, rollout, adv, ret, cfg.ppo, bc_weight=1.0)[1]["bc_loss"]
    assert plain == pytest.approx(-float(out.target_log_prob[active].mean()), rel=1e-5)


def test_steps_since_collision_counts_up_to_the_window_and_restarts_on_a_collision():
    from collavn.training.trainer import steps_since_collision

    since = np.array([[3, 0, 1]])
    hit = np.array([[False, False, True]])
    assert steps_since_collision(since, hit, 3).tolist() == [[3, 1, 0]]
    assert steps_since_collision(since, ~hit, 3).tolist() == [[0, 0, 2]]
    assert since.tolist() == [[3, 0, 1]]  # a new array


def test_blocked_steps_weigh_the_anchor_only_just_after_a_collision(
        il_checkpoint, tmp_path, monkeypatch):
    cfg = tiny_config(method="no-com", out=str(tmp_path / "ft"), rollout_steps=12
                      ).with_run(init_from=str(il_checkpoint))
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(
        cfg.ppo, bc_coef=1.0, bc_target="init", bc_steps="blocked", bc_blocked_window=3))
    assert not env_config(cfg).privileged  # the collision flags are the env's info
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    # the env reports collisions of agent 0 in env 0 on steps 2 and 4 only
    step, calls = run.env.step, []

    def stepped(actions):
        obs, reward, terminated, truncated, info = step(actions)
        info["collided"] = np.zeros_like(info["collided"])
        info["collided"][0, 0] = len(calls) in (2, 4)
        calls.append(int(obs["step"][0, 0]))
        return obs, reward, terminated, truncated, info

    monkeypatch.setattr(run.env, "step", stepped)
    rollout, _ = collect_rollout(run)
    assert rollout.weights is not None and len(calls) == cfg.ppo.rollout_steps
    assert not rollout.episode_start[1:10, 0, 0].any()  # one episode over these steps
    # weighed: steps 3, 4, 5 (after step 2's collision), 5, 6, 7 (after step 4's)
    assert rollout.weights[:10, 0, 0].tolist() == [0, 0, 0, 1, 1, 1, 1, 1, 0, 0]
    assert not rollout.weights[:, 1:].any() and not rollout.weights[:, 0, 1].any()
    # the next rollout goes on counting from where this one stopped
    assert run.since_collision is not None and run.since_collision[0, 0] == 3


def test_blocked_window_is_a_positive_count():
    with pytest.raises(ConfigError, match=r"--ppo\.bc-blocked-window"):
        PPOConfig(bc_steps="blocked", bc_blocked_window=0)
    with pytest.raises(ConfigError, match=r"--ppo\.bc-steps must be all, sighted or blocked"):
        PPOConfig(bc_steps="bumped")  # type: ignore[arg-type]
