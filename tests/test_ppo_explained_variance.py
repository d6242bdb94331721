"""The critic's explained variance, logged by every PPO update."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from collavn.training.distributed import DistInfo
from collavn.training.ppo import explained_variance
from collavn.training.rollout import compute_gae
from collavn.training.trainer import build_run, collect_rollout, learn, sync_point
from training_fixtures import tiny_config


def test_explained_variance_by_hand():
    returns = torch.tensor([1.0, 2.0, 3.0, 4.0])
    every = torch.ones(4, dtype=torch.bool)
    assert explained_variance(returns.clone(), returns, every) == pytest.approx(1.0)
    # the returns' mean explains nothing
    assert explained_variance(torch.full((4,), 2.5), returns, every) == pytest.approx(0.0)
    # residuals 1, −1, 1, −1: Var = 1 against Var(R) = 1.25
    values = returns + torch.tensor([1.0, -1.0, 1.0, -1.0])
    assert explained_variance(values, returns, every) == pytest.approx(1 - 1 / 1.25)
    # worse than the mean: below 0
    assert explained_variance(-returns, returns, every) < 0.0


def test_explained_variance_reads_only_masked_steps_and_is_nan_with_nothing_to_explain():
    returns = torch.tensor([[1.0, 100.0], [3.0, -50.0]])
    mask = torch.tensor([[True, False], [True, False]])
    values = torch.tensor([[1.0, 0.0], [3.0, 0.0]])  # exact where it counts
    assert explained_variance(values, returns, mask) == pytest.approx(1.0)
    assert math.isnan(explained_variance(values, torch.ones(2, 2), mask))
    assert math.isnan(explained_variance(values, returns, torch.zeros(2, 2, dtype=torch.bool)))


def test_learn_logs_the_collected_values_explained_variance():
    cfg = tiny_config(method="ours", rollout_steps=8)
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    rollout, _ = collect_rollout(run)
    _, returns = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                             rollout.truncated, rollout.last_value, cfg.ppo.gamma,
                             cfg.ppo.gae_lambda)
    expected = explained_variance(rollout.values, returns, rollout.active)
    losses = learn(run, rollout)
    assert np.isfinite(expected)
    assert losses["loss/explained_variance"] == pytest.approx(expected)
