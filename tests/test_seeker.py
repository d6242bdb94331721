"""The seeker: the explorer's moves until the goal is in sight, the oracle's after."""


from dataclasses import replace

import numpy as np
import pytest
import torch

from collavn.datasets.generator import sample_episodes
from collavn.envs import EnvConfig
from collavn.envs.vector import VectorEnv
from collavn.errors import CollavnError, ConfigError
from collavn.evaluation.runner import evaluate
from collavn.metrics import compute_metrics
from collavn.policies import ExplorerPolicy, OraclePolicy, SeekerPolicy, make_policy
from collavn.scenes import load_scene
from collavn.training.config import ImitationConfig
from collavn.training.distributed import DistInfo
from collavn.training.trainer import build_run, collect_rollout, env_config, sync_point
from training_fixtures import tiny_config

SMALL = EnvConfig(num_agents=2, panorama_width=64, panorama_height=16, goal_size=8,
                  depth=True, privileged=True, difficulty="easy")


@pytest.fixture(scope="module")
def apartment():
    return load_scene("procedural:1001")


def test_seeker_explores_out_of_sight_and_homes_in_sight_for_the_rest_of_the_episode(
        apartment):
    env = VectorEnv([apartment], 1, replace(SMALL, explore_action=True), seed=3)
    obs, _ = env.reset(seed=3)
    seeker = SeekerPolicy([apartment], sight=2.0)
    explorer = ExplorerPolicy(0, open_fraction=1.0, deterministic=True)
    oracle = OraclePolicy([apartment])
    pose, goal = obs["world_pose"][0], obs["goal_position"][0]
    far = np.array([goal[0, 0] + 50.0, goal[0, 1]])  # nowhere near: never in sight
    near = pose[1, :2].copy()                         # where agent 1 stands: in sight
    obs["goal_position"] = np.stack([far, near])[None]
    state = seeker.initial_state(1, 2)
    actions, state = seeker.act(obs, state)
    expected_explore, _ = explorer.act(obs, explorer.initial_state(1, 2))
    np.testing.assert_array_equal(actions[0, 0], expected_explore[0, 0])
    # the search move is the explore_action sensor's: what a learner reads (explore_prior)
    np.testing.assert_array_equal(actions[0, 0].astype(np.float32), obs["explore_action"][0, 0])
    np.testing.assert_array_equal(actions[0, 1], oracle.act_one(apartment, pose, 1, near))
    assert state.seen.tolist() == [[False, True]]
    # Out of sight again later in the episode: still homing (the latch) …
    obs["goal_position"] = np.stack([far, far])[None]
    obs["step"] = np.ones_like(obs["step"])
    _, state = seeker.act(obs, state)
    assert state.seen.tolist() == [[False, True]]
    # … until that agent's next episode starts.
    obs["step"] = np.array([[1, 0]])
    _, state = seeker.act(obs, state)
    assert state.seen.tolist() == [[False, False]]


def test_seeker_needs_privileged_observations_and_a_positive_sight():
    policy, overrides = make_policy("seeker", [], seed=0)
    assert overrides == {"privileged": True, "depth": True}
    with pytest.raises(KeyError, match="privileged"):
        policy.act({"depth": np.zeros((1, 1, 16, 64)), "active": np.ones((1, 1), bool)},
                   policy.initial_state(1, 1))
    with pytest.raises(CollavnError, match="sight"):
        SeekerPolicy([], sight=0.0)
    with pytest.raises(ConfigError, match="sight"):
        ImitationConfig(expert="seeker", sight=float("nan"))


def test_seeker_scores_between_explorer_and_oracle_and_repeats_itself(apartment):
    episodes = sample_episodes(apartment, "commongoal", 2, "medium", 16,
                               np.random.default_rng(0))
    explorer = evaluate(ExplorerPolicy(0), apartment, episodes, SMALL, num_envs=8, seed=0)
    runs = [evaluate(SeekerPolicy([apartment]), apartment, episodes, SMALL, num_envs=n, seed=0)
            for n in (8, 5)]
    assert runs[0].records == runs[1].records  # deterministic, whatever the batch size
    oracle = evaluate(OraclePolicy([apartment]), apartment, episodes, SMALL, num_envs=8, seed=0)
    sr = {name: compute_metrics(r.records)["SR"]
          for name, r in (("explorer", explorer), ("seeker", runs[0]), ("oracle", oracle))}
    assert sr["explorer"] <= sr["seeker"] <= sr["oracle"], sr
    assert sr["seeker"] >= sr["explorer"] + 0.1, sr


def test_il_with_the_seeker_stores_its_actions_as_targets():
    cfg = tiny_config(method="il", rollout_steps=5,
                      imitation=ImitationConfig(expert="seeker", dagger=False))
    assert env_config(cfg).depth and env_config(cfg).privileged
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    assert run.expert is not None and isinstance(run.expert.policy, SeekerPolicy)
    twin = SeekerPolicy(list(run.env.scenes), cfg.imitation.sight, seed=cfg.run.seed)
    twin_state = twin.initial_state(run.env.num_envs, run.env.num_agents)
    obs = run.obs
    first, twin_state = twin.act(obs, twin_state)  # β = 1: the seeker drives
    rollout, _ = collect_rollout(run)
    np.testing.assert_allclose(rollout.raw_actions[0].numpy(), first, atol=1e-6)
    assert rollout.raw_actions.abs().sum() > 0


def test_an_unknown_expert_is_refused():
    with pytest.raises(ConfigError, match="oracle or seeker"):
        ImitationConfig(expert="teacher")  # type: ignore[arg-type]
