import json

import numpy as np
import pytest
import torch

from collavn.cli import main
from collavn.datasets.generator import sample_episodes
from collavn.envs import EnvConfig
from collavn.evaluation.runner import evaluate, first_sightings, read_records, write_records
from collavn.metrics import compute_metrics
from collavn.policies import OraclePolicy, RandomPolicy


def _linear_rounds_rows_by_position(in_features: int = 67, out_features: int = 8,
                                    rows: int = 16) -> bool:
    """Whether this machine's BLAS rounds a row of ``x @ Wᵀ`` by its position in the batch.

    The shape is the tiny test model's key projection (67 → 8) over one block of 8 envs ×
    2 agents, on one thread as in the tests. Kernels for Intel's AVX-512 round every row
    alike (the Intel AVX-512 VMs, where the memory variant's ``num_envs`` test passed);
    those torch's BLAS picks on AVX2 CPUs and on an AMD EPYC with AVX-512 (2026-12-07)
    do not.
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        g = torch.Generator().manual_seed(0)
        w = torch.randn(out_features, in_features, generator=g)
        b = torch.randn(out_features, generator=g)
        x = torch.randn(rows, in_features, generator=g)
        y = torch.nn.functional.linear(x, w, b)
        return any(not torch.equal(torch.roll(torch.nn.functional.linear(
            torch.roll(x, k, 0), w, b), -k, 0), y) for k in range(1, rows))
    finally:
        torch.set_num_threads(threads)


_SLOT_ROUNDING = _linear_rounds_rows_by_position()
SMALL = EnvConfig(num_agents=2, panorama_width=32, panorama_height=8, goal_size=8)


@pytest.fixture(scope="module")
def easy_episodes(door_scene):
    return sample_episodes(door_scene, "commongoal", 2, "easy", 6, np.random.default_rng(0))


def test_every_episode_is_recorded_exactly_once(door_scene, easy_episodes):
    result = evaluate(RandomPolicy(0), door_scene, easy_episodes, SMALL, num_envs=4,
                      keep_trajectories=2)
    ids = [r.episode_id for r in result.records]
    assert len(ids) == 2 * len(easy_episodes)
    assert [ids[2 * k] for k in range(len(easy_episodes))] == [
        e.episode_id for e in easy_episodes]
    assert [t.episode_id for t in result.trajectories] == [e.episode_id
                                                           for e in easy_episodes[:2]]
    traj = result.trajectories[0]
    np.testing.assert_allclose(traj.poses[0, :, :2], easy_episodes[0].start_positions)


def test_oracle_reaches_easy_goals_and_random_does_much_worse(door_scene, easy_episodes):
    from dataclasses import replace

    oracle = evaluate(OraclePolicy([door_scene]), door_scene, easy_episodes,
                      replace(SMALL, privileged=True))
    rand = evaluate(RandomPolicy(0), door_scene, easy_episodes, SMALL)
    assert compute_metrics(oracle.records)["SR"] >= 0.9
    assert compute_metrics(rand.records)["SR"] < compute_metrics(oracle.records)["SR"] - 0.3
    for r in oracle.records:
        assert r.success == (r.final_distance <= 1.0)


def test_first_sighting_needs_the_goal_near_and_the_straight_way_free(door_scene):
    goal = np.array([[6.0, 1.5]])
    path = np.array([[4.0, 1.5, 0.0],   # 2.0 m away, but the wall is in between
                     [4.5, 3.5, 0.0],   # 2.5 m: too far
                     [5.5, 3.5, 0.0],   # in the door, 2.06 m: too far
                     [5.6, 3.0, 0.0],   # 1.55 m, the straight way free: in sight
                     [6.0, 2.0, 0.0]])[:, None]
    assert first_sightings(door_scene, path, goal, [4]) == [3]
    assert first_sightings(door_scene, path, goal, [2]) == [-1]  # it stopped before
    assert first_sightings(door_scene, path, goal, [4], sight=1.0) == [4]
    assert first_sightings(door_scene, path[:1], goal, [0], sight=2.5) == [-1]  # wall


def test_evaluation_records_when_each_agent_first_sighted_its_goal(door_scene,
                                                                   easy_episodes):
    from dataclasses import replace

    oracle = evaluate(OraclePolicy([door_scene]), door_scene, easy_episodes,
                      replace(SMALL, privileged=True), keep_trajectories=len(easy_episodes))
    by_id = {t.episode_id: t for t in oracle.trajectories}
    for r in oracle.records:
        assert r.sighted_step is not None and r.sighted_step <= r.steps
        traj = by_id[r.episode_id]
        want = first_sightings(door_scene, traj.poses[:, r.agent:r.agent + 1],
                               traj.goals[r.agent:r.agent + 1], [r.steps])
        assert [r.sighted_step] == want
        if r.success:
            assert r.sighted_step >= 0


def test_oracle_without_privileged_observations_explains_itself(door_scene, easy_episodes):
    with pytest.raises(KeyError, match="privileged"):
        evaluate(OraclePolicy([door_scene]), door_scene, easy_episodes[:1], SMALL)


def test_evaluation_is_deterministic_and_records_round_trip(door_scene, easy_episodes,
                                                            tmp_path):
    a = evaluate(RandomPolicy(3), door_scene, easy_episodes, SMALL, seed=1).records
    b = evaluate(RandomPolicy(3), door_scene, easy_episodes, SMALL, seed=1).records
    assert a == b
    path = write_records(tmp_path / "r.jsonl", a)
    assert read_records(path) == a


def test_cli_chain_generate_evaluate_viz(door_scene, tmp_path, capsys):
    scene_file = tmp_path / "door.npz"
    door_scene.save(scene_file)
    data, out = tmp_path / "data", tmp_path / "eval"
    assert main(["dataset", "generate", "--task", "commongoal", "--agents", "2", "--split",
                 "val", "--preset", "small", "--scenes", str(scene_file), "--out", str(data),
                 "--quiet"]) == 0
    assert "door.json.gz" in capsys.readouterr().out  # the files it wrote
    assert main(["dataset", "info", str(data), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["episodes"] == 30
    assert main(["evaluate", "--policy", "oracle", "--dataset", str(data), "--out", str(out),
                 "--panorama-width", "32", "--panorama-height", "8", "--goal-size", "8",
                 "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    assert table["oracle"]["metrics"]["overall"]["SR"] >= 0.85
    assert len(read_records(out / "records.jsonl")) == 60
    assert (out / "metrics.tex").read_text().count("oracle") == 1
    assert table["oracle"]["search"]["overall"]["homing"] >= 0.85
    assert "SR once sighted (homing)" in (out / "metrics.md").read_text()
    assert main(["viz", str(out), "--out", str(tmp_path / "viz"), "--panorama-width",
                 "32"]) == 0
    assert (tmp_path / "viz" / "trajectories.png").stat().st_size > 10_000
    assert len(list((tmp_path / "viz").glob("episode_*.gif"))) == 1


def test_cli_episode_count_override_and_difficulty_filter(door_scene, tmp_path, capsys):
    scene_file = tmp_path / "door.npz"
    door_scene.save(scene_file)
    data = tmp_path / "data"
    assert main(["dataset", "generate", "--split", "test", "--episodes", "3", "--scenes",
                 str(scene_file), "--out", str(data), "--quiet"]) == 0
    capsys.readouterr()
    assert main(["dataset", "info", str(data), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["episodes"] == 9  # 3 per difficulty
    assert main(["evaluate", "--policy", "random", "--dataset", str(data), "--difficulty",
                 "easy", "--out", str(tmp_path / "eval"), "--panorama-width", "32",
                 "--panorama-height", "8", "--goal-size", "8", "--json"]) == 0
    table = json.loads(capsys.readouterr().out)
    assert set(table["random"]["counts"]) >= {"easy"}
    records = read_records(tmp_path / "eval" / "records.jsonl")
    assert len(records) == 6 and {r.difficulty for r in records} == {"easy"}
    assert main(["dataset", "generate", "--episodes", "0", "--scenes", str(scene_file),
                 "--out", str(data), "--quiet"]) == 2
    assert "--episodes must be" in capsys.readouterr().err


def test_cli_errors_are_short_and_named(tmp_path, capsys):
    assert main(["evaluate", "--policy", "nonsense", "--dataset", str(tmp_path)]) == 2
    assert "not an episode dataset" in capsys.readouterr().err
    assert main(["scene", "info", "procedural:x"]) == 2
    assert "seed must be an integer" in capsys.readouterr().err
    assert main(["no-such-command"]) == 2
    assert main(["--help"]) == 0
    assert "demo" in capsys.readouterr().out


def test_demo_runs_end_to_end(tmp_path, capsys):
    assert main(["demo", "--scene", "procedural:1", "--out", str(tmp_path), "--episodes",
                 "1", "--panorama-width", "64"]) == 0
    printed = capsys.readouterr().out
    assert "| oracle |" in printed and "| random |" in printed
    assert (tmp_path / "scene_map.png").is_file()
    assert (tmp_path / "oracle" / "trajectories.png").is_file()
    assert list((tmp_path / "oracle").glob("*.gif"))


def _untrained_checkpoint(path, method: str, seed: int = 0, listen: bool = True,
                          actor_hears: bool = True):
    from dataclasses import replace

    import torch

    from collavn.models.policy import ActorCritic
    from collavn.policies.checkpoint import save_checkpoint
    from training_fixtures import tiny_config

    cfg = tiny_config(method).with_env(panorama_width=32, panorama_height=8, goal_size=8)
    cfg = replace(cfg, model=replace(cfg.model, comm=replace(
        cfg.model.comm, listen=listen, actor_hears=actor_hears)))
    torch.manual_seed(seed)
    save_checkpoint(path, {"config": cfg.to_dict(), "iteration": 0,
                           "model": ActorCritic(cfg.model).state_dict()})
    return path


def test_evaluation_reports_communication_per_method(door_scene, tmp_path, capsys):
    scene_file = tmp_path / "door.npz"
    door_scene.save(scene_file)
    data = tmp_path / "data"
    assert main(["dataset", "generate", "--split", "val", "--episodes", "2", "--scenes",
                 str(scene_file), "--out", str(data), "--quiet"]) == 0
    small = ["--panorama-width", "32", "--panorama-height", "8", "--goal-size", "8"]
    rates = {}
    for name in ("random", "oracle", "ours", "no-com"):
        policy = name if name in ("random", "oracle") else str(  # seed 15: mixed gates
            _untrained_checkpoint(tmp_path / f"{name}.pt", name, seed=15))
        capsys.readouterr()
        assert main(["evaluate", "--policy", policy, "--dataset", str(data), "--out",
                     str(tmp_path / name), "--json", *small]) == 0
        rates[name] = json.loads(capsys.readouterr().out)[policy]["communication"]
        assert "comm. received" in (tmp_path / name / "metrics.md").read_text()
    zero = {"received_rate": 0.0, "when_rate": 0.0, "bytes_per_agent_step": 0.0}
    assert rates["random"] == rates["oracle"] == rates["no-com"] == zero
    assert 0.0 < rates["ours"]["received_rate"] < 1.0
    assert rates["ours"]["received_rate"] <= rates["ours"]["when_rate"]
    assert rates["ours"]["bytes_per_agent_step"] > 0
    # the --mute ablation: the same checkpoint, links to teammates cut
    assert main(["evaluate", "--policy", str(tmp_path / "ours.pt"), "--mute", "--dataset",
                 str(data), "--out", str(tmp_path / "muted"), "--json", *small]) == 0
    muted = json.loads(capsys.readouterr().out)[str(tmp_path / "ours.pt")]["communication"]
    assert muted["received_rate"] == muted["bytes_per_agent_step"] == 0.0
    assert muted["when_rate"] > 0.0  # its own gate still opens
    # the same weights trained --model.comm.no-listen: muted without --mute, and the same
    deaf = str(_untrained_checkpoint(tmp_path / "deaf.pt", "ours", seed=15, listen=False))
    assert main(["evaluate", "--policy", deaf, "--dataset", str(data), "--out",
                 str(tmp_path / "deaf"), "--json", *small]) == 0
    assert json.loads(capsys.readouterr().out)[deaf]["communication"] == muted
    assert ((tmp_path / "deaf" / "records.jsonl").read_text()
            == (tmp_path / "muted" / "records.jsonl").read_text())
    # trained --model.comm.no-actor-hears (only its critic heard): it acts deaf
    blind = str(_untrained_checkpoint(tmp_path / "blind.pt", "ours", seed=15,
                                      actor_hears=False))
    assert main(["evaluate", "--policy", blind, "--dataset", str(data), "--out",
                 str(tmp_path / "blind"), "--json", *small]) == 0
    assert json.loads(capsys.readouterr().out)[blind]["communication"] == muted
    assert ((tmp_path / "blind" / "records.jsonl").read_text()
            == (tmp_path / "muted" / "records.jsonl").read_text())
    for policy, why in (("random", "the random policy sends none"),
                        (str(tmp_path / "no-com.pt"), "has no communication"),
                        (deaf, "no-listen: its agents hear no teammate"),
                        (blind, "no-actor-hears: its actor hears no teammate")):
        # refused before --overwrite moves an earlier result aside
        assert main(["evaluate", "--policy", policy, "--mute", "--dataset", str(data),
                     "--out", str(tmp_path / "muted"), "--overwrite", *small]) == 2
        assert why in capsys.readouterr().err
        assert (tmp_path / "muted" / "records.jsonl").is_file()
        assert not list(tmp_path.glob("muted.old-*"))


def _block_runs(door_scene, variant: str, seed: int):
    """Records of one tiny checkpoint policy at 3, 8 and 11 envs (blocks of 8)."""
    from dataclasses import replace

    import torch

    from collavn.models.policy import ActorCritic
    from collavn.policies.checkpoint import CheckpointPolicy
    from training_fixtures import TINY_MODEL

    torch.set_num_threads(1)
    torch.manual_seed(seed)
    model = ActorCritic(replace(TINY_MODEL, panorama_shape=(3, 16, 64), goal_shape=(3, 16, 16),
                                comm=replace(TINY_MODEL.comm, variant=variant)))
    env = replace(SMALL, panorama_width=64, panorama_height=16, goal_size=16, max_steps=12)
    episodes = sample_episodes(door_scene, "commongoal", 2, "medium", 11,
                               np.random.default_rng(1))
    with pytest.raises(KeyError, match=r"reads free_space, which the observation lacks"):
        evaluate(CheckpointPolicy(model), door_scene, episodes[:1], env)
    env = replace(env, free_space=TINY_MODEL.free_space_input)
    return [evaluate(CheckpointPolicy(model, stochastic=True, seed=2), door_scene, episodes,
                     env, num_envs=k).records for k in (3, 8, 11)]


@pytest.mark.parametrize("seed", [0, 1])
def test_a_checkpoint_policy_scores_the_same_for_any_num_envs(door_scene, seed):
    """Fixed-size blocks of envs: 3, 8 or 11 envs at once give bit-identical records."""
    runs = _block_runs(door_scene, "none", seed)
    assert runs[0] == runs[1] == runs[2]
    assert len({r.final_distance for r in runs[0]}) > 1


@pytest.mark.xfail(_SLOT_ROUNDING, strict=False,
                   reason="this machine's BLAS rounds the tiny test model's 67→8 key "
                   "projection differently by a row's position in the block (measured by "
                   "_linear_rounds_rows_by_position: AVX2 CPUs, AMD EPYC), so an episode's "
                   "results depend on the slot it ran in; where every slot rounds alike "
                   "(Intel AVX-512) the test must pass; the presets' shapes are "
                   "slot-independent everywhere tried (next test); block_envs=1 is exact")
def test_a_communicating_policy_scores_the_same_for_any_num_envs(door_scene):
    runs = _block_runs(door_scene, "memory", 1)
    assert runs[0] == runs[1] == runs[2]


@pytest.mark.parametrize("variant", ["none", "memory"])
def test_a_cpu_preset_model_gives_an_env_the_same_result_in_any_slot_of_a_block(variant):
    """What makes ``num_envs`` irrelevant for the shipped sizes: slot-independent rounding."""
    from dataclasses import replace

    import torch

    from collavn.models import ActorCritic, ModelConfig
    from collavn.policies.checkpoint import BLOCK_ENVS

    torch.set_num_threads(1)
    torch.manual_seed(0)
    cfg = ModelConfig.cpu()
    model = ActorCritic(replace(cfg, comm=replace(cfg.comm, variant=variant))).eval()
    e, n = BLOCK_ENVS, 2
    g = torch.Generator().manual_seed(0)
    obs = dict(
        panorama=torch.randint(0, 256, (e, n, *cfg.panorama_shape), generator=g,
                               dtype=torch.uint8),
        goal=torch.randint(0, 256, (e, n, *cfg.goal_shape), generator=g, dtype=torch.uint8),
        pose_delta=torch.randn(e, n, 3, generator=g) * 0.3,
        free_space=torch.rand(e, n, cfg.free_space_input, generator=g) * 4.0,
        active=torch.ones(e, n, dtype=torch.bool))
    start = torch.ones(e, n, dtype=torch.bool)

    def two_steps(order):
        o = {k: v[order] for k, v in obs.items()}
        with torch.no_grad():
            first = model(o, model.initial_state(e, n), start)
            second = model(o, first.state, ~start)
        return first, second

    a1, a2 = two_steps(torch.arange(e))
    for slot in range(1, e):  # env 0 swapped into every other slot
        order = torch.arange(e)
        order[0], order[slot] = slot, 0
        b1, b2 = two_steps(order)
        assert torch.equal(a1.dist.mean[0], b1.dist.mean[slot])
        assert torch.equal(a2.dist.mean[0], b2.dist.mean[slot])
        assert torch.equal(a2.value[0], b2.value[slot])
        assert torch.equal(a2.message.omega[0], b2.message.omega[slot])


def test_trajectory_maps_mark_where_each_agent_first_sighted_its_goal(door_scene):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from collavn.evaluation.runner import Trajectory
    from collavn.viz.trajectories import draw_trajectory

    # agent 0 walks through the door to the goal (in sight at step 3); agent 1 stays
    # behind the wall, 2 m from the goal but never in sight
    a0 = [[4.0, 1.5], [4.5, 3.5], [5.5, 3.5], [5.6, 3.0], [6.0, 2.0]]
    a1 = [[4.0, 1.5]] * 5
    poses = np.zeros((5, 2, 3))
    poses[:, 0, :2], poses[:, 1, :2] = a0, a1
    traj = Trajectory("e", door_scene.spec, poses, np.array([[6.0, 1.5]] * 2),
                      np.zeros(2), np.array([True, False]))
    fig, ax = plt.subplots()
    draw_trajectory(ax, door_scene, traj)
    diamonds = [line for line in ax.lines if line.get_marker() == "D"]
    assert len(diamonds) == 1
    np.testing.assert_allclose(diamonds[0].get_xydata(), [[5.6, 3.0]])
    assert diamonds[0].get_label() == "goal first in sight"
    plt.close(fig)
