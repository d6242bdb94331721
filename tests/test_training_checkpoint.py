"""Checkpoints: atomic writes, refusal of another config, resume == uninterrupted run."""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from collavn.cli.train import parse
from collavn.errors import CheckpointError, ConfigError
from collavn.policies.checkpoint import load_checkpoint, load_policy, save_checkpoint
from collavn.training.checkpoint import SNAPSHOTS, run_snapshots, saved_config
from collavn.training.trainer import CHECKPOINT, train
from training_fixtures import tiny_config


def _params(path: Path) -> dict[str, torch.Tensor]:
    return load_checkpoint(path)["model"]


def test_save_is_atomic_and_leaves_the_old_file_on_failure(tmp_path, monkeypatch):
    path = tmp_path / "ck.pt"
    save_checkpoint(path, {"x": torch.arange(3)})

    def broken_save(obj, f):
        f.write(b"half a checkpoint")
        raise OSError("disk full")

    monkeypatch.setattr(torch, "save", broken_save)
    with pytest.raises(OSError):  # while serialising, before any file is touched
        save_checkpoint(path, {"x": torch.arange(5)})
    monkeypatch.undo()
    assert load_checkpoint(path)["x"].tolist() == [0, 1, 2]
    assert sorted(os.listdir(tmp_path)) == ["ck.pt"]  # no temp file left behind


def test_corrupt_or_foreign_files_are_refused(tmp_path):
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="cannot read"):
        load_checkpoint(tmp_path / "bad.pt")
    torch.save({"model": {}}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not a collavn"):
        load_checkpoint(tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="no checkpoint"):
        load_checkpoint(tmp_path / "missing.pt")
    torch.save({"format": 1, "config": {}, "model": {}}, tmp_path / "old.pt")
    with pytest.raises(CheckpointError, match=r"format 1.*communication semantics changed"):
        load_checkpoint(tmp_path / "old.pt")


@pytest.fixture(scope="module")
def resumed_and_straight(tmp_path_factory):
    """4 updates straight vs 2 updates, stop, resume for 2 more (sync every 2); both keep
    a snapshot per agent-steps of one update (written at the sync points: 2 and 4)."""
    root = tmp_path_factory.mktemp("resume")
    cfg = tiny_config("ours", out=str(root / "straight"))
    per_update = cfg.ppo.rollout_steps * cfg.run.num_envs * cfg.env.num_agents
    cfg = cfg.with_run(snapshot_every=per_update)
    straight = train(cfg.with_run(total_steps=4 * per_update))
    part = cfg.with_run(out=str(root / "resumed"), total_steps=2 * per_update)
    first = train(part)
    # the first half's checkpoint continued in another directory, then in place
    train(part.with_run(out=str(root / "extended"), total_steps=4 * per_update,
                        resume_from=str(root / "resumed" / CHECKPOINT)))
    resumed = train(part.with_run(total_steps=4 * per_update, resume=True))
    return cfg, root, straight, first, resumed


def test_resume_gives_bit_identical_parameters(resumed_and_straight):
    _, root, straight, first, resumed = resumed_and_straight
    assert (first.iterations, resumed.iterations, straight.iterations) == (2, 4, 4)
    a, b = _params(root / "straight" / CHECKPOINT), _params(root / "resumed" / CHECKPOINT)
    c = _params(root / "extended" / CHECKPOINT)  # --resume-from the first half
    assert a.keys() == b.keys() == c.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k
        assert torch.equal(a[k], c[k]), k
    assert load_checkpoint(root / "extended" / CHECKPOINT)["iteration"] == 4
    # ...and training did change them.
    fresh = tiny_config("ours")
    torch.manual_seed(fresh.run.seed)
    from collavn.models.policy import ActorCritic

    init = ActorCritic(fresh.model).state_dict()
    assert any(not torch.equal(init[k], a[k]) for k in a)


def test_snapshots_keep_the_checkpoints_of_a_learning_curve(resumed_and_straight):
    cfg, root, *_ = resumed_and_straight
    per_update = cfg.run.snapshot_every
    names = [f"checkpoint_{2 * per_update:09d}.pt", f"checkpoint_{4 * per_update:09d}.pt"]
    for run in ("straight", "resumed"):  # the resumed run goes on from its marks
        assert sorted(p.name for p in (root / run / SNAPSHOTS).iterdir()) == names, run
    early, last = (root / "straight" / SNAPSHOTS / n for n in names)
    assert load_checkpoint(early)["iteration"] == 2
    assert load_checkpoint(last)["iteration"] == 4
    final = _params(root / "straight" / CHECKPOINT)
    for k, v in _params(last).items():
        assert torch.equal(v, final[k]), k
    assert any(not torch.equal(v, final[k]) for k, v in _params(early).items())
    for name in names:  # resumed == straight, snapshot by snapshot
        a = _params(root / "straight" / SNAPSHOTS / name)
        b = _params(root / "resumed" / SNAPSHOTS / name)
        assert all(torch.equal(a[k], b[k]) for k in a), name
    _, overrides = load_policy(early)  # what `collavn evaluate --policy` loads
    assert overrides["panorama_width"] == cfg.env.panorama_width
    with pytest.raises(ConfigError, match="--snapshot-every must be an integer ≥ 0, got -1"):
        parse(["--method", "no-com", "--snapshot-every", "-1", "--out", "x"])
    assert parse(["--method", "no-com", "--out", "x"]).run.snapshot_every == 0  # off


def test_average_of_snapshots_is_the_mean_of_their_weights(resumed_and_straight, tmp_path,
                                                           capsys):
    from collavn.cli import main
    from collavn.training.checkpoint import average_checkpoints

    cfg, root, *_ = resumed_and_straight
    per_update = cfg.run.snapshot_every
    paths = sorted((root / "straight" / SNAPSHOTS).iterdir())
    assert main(["average", *map(str, paths), "--out", str(tmp_path / "avg.pt")]) == 0
    assert "averaged 2 checkpoints" in capsys.readouterr().out
    avg = load_checkpoint(tmp_path / "avg.pt")
    a, b = (_params(p) for p in paths)
    floats = 0
    for k, v in avg["model"].items():
        if torch.is_floating_point(v):
            floats += 1
            assert torch.equal(v, ((a[k].double() + b[k].double()) / 2).float()), k
        else:  # integer buffers: the later checkpoint's
            assert torch.equal(v, b[k]), k
    assert floats > 10 and any(not torch.equal(a[k], b[k]) for k in a)
    assert avg["iteration"] == 4  # counters and config: the checkpoint with most steps
    assert [s["agent_steps"] for s in avg["averaged_from"]] == [
        load_checkpoint(p)["agent_steps"] for p in paths]
    policy, _ = load_policy(tmp_path / "avg.pt")  # an evaluation policy with those weights
    loaded = policy.model.state_dict()
    assert all(torch.equal(loaded[k], v) for k, v in avg["model"].items())
    # a policy to evaluate or --init-from, not a run's state to resume
    with pytest.raises(CheckpointError, match=r"average of 2 checkpoints.*--init-from"):
        train(cfg.with_run(out=str(tmp_path / "again"), total_steps=8 * per_update,
                           resume_from=str(tmp_path / "avg.pt")))
    # the same inputs give the same weights, in any order
    again = average_checkpoints(paths[::-1])["model"]
    assert all(torch.equal(again[k], avg["model"][k]) for k in again)
    # a run directory stands for its second half's snapshots: here both (2 and 4 updates)
    assert main(["average", str(root / "straight"), "--out", str(tmp_path / "run.pt")]) == 0
    assert "averaged 2 checkpoints" in capsys.readouterr().out
    by_dir = load_checkpoint(tmp_path / "run.pt")["model"]
    assert all(torch.equal(by_dir[k], avg["model"][k]) for k in by_dir)
    assert run_snapshots(root / "straight", from_steps=3 * per_update) == paths[1:]
    assert run_snapshots(root / "straight", from_steps=0) == paths
    with pytest.raises(ConfigError, match="--from-steps must be ≥ 0, got -1"):
        run_snapshots(root / "straight", from_steps=-1)


def test_average_refuses_one_file_and_another_configuration(resumed_and_straight, tmp_path,
                                                            capsys):
    from collavn.cli import main
    from collavn.training.checkpoint import average_checkpoints

    _, root, *_ = resumed_and_straight
    good = root / "straight" / CHECKPOINT
    with pytest.raises(CheckpointError, match="at least two checkpoints"):
        average_checkpoints([good])
    other = load_checkpoint(good)
    other["config"]["ppo"]["lr"] = 1.0
    save_checkpoint(tmp_path / "other.pt", {k: v for k, v in other.items() if k != "format"})
    with pytest.raises(CheckpointError, match=r"another configuration .*ppo\.lr"):
        average_checkpoints([good, tmp_path / "other.pt"])
    assert main(["average", str(good), str(tmp_path / "missing.pt"),
                 "--out", str(tmp_path / "x.pt")]) == 2
    assert "no checkpoint at" in capsys.readouterr().err
    assert not (tmp_path / "x.pt").exists()
    # a run directory: no snapshots folder, none late enough, --from-steps with files
    with pytest.raises(CheckpointError, match=r"holds no snapshots/ folder.*--snapshot-every"):
        run_snapshots(tmp_path)
    last = load_checkpoint(good)["agent_steps"]
    assert main(["average", str(root / "straight"), "--from-steps", str(last + 1),
                 "--out", str(tmp_path / "x.pt")]) == 2
    assert f"no snapshot at or after {last + 1:,} agent-steps" in capsys.readouterr().err
    assert main(["average", str(good), str(good), "--from-steps", "0",
                 "--out", str(tmp_path / "x.pt")]) == 2
    assert "--from-steps picks a run directory's snapshots" in capsys.readouterr().err
    assert not (tmp_path / "x.pt").exists()


def test_pick_keeps_the_snapshot_best_on_train_episodes(resumed_and_straight, tmp_path,
                                                       capsys):
    from collavn.cli import main
    from collavn.evaluation.benchmark import EvalConfig, load_dataset, run_evaluation
    from collavn.evaluation.compare import sr_interval

    _, root, *_ = resumed_and_straight
    data = tmp_path / "train_eps"
    assert main(["dataset", "generate", "--task", "commongoal", "--agents", "2", "--split",
                 "train", "--episodes", "6", "--scenes", "procedural:0", "--out", str(data),
                 "--quiet"]) == 0
    capsys.readouterr()
    out = tmp_path / "picked.pt"
    assert main(["pick", str(root / "straight"), "--dataset", str(data), "--out", str(out),
                 "--num-envs", "3", "--torch-threads", "1", "--no-progress"]) == 0
    printed = capsys.readouterr().out
    picked = load_checkpoint(out)
    paths = run_snapshots(root / "straight")
    assert len(paths) == 2 and [r["path"] for r in picked["picked_from"]] == list(map(str, paths))
    # each score is the snapshot's own mean-action SR on the easy + medium train episodes
    for path, row in zip(paths, picked["picked_from"], strict=True):
        cfg = EvalConfig(policy=str(path), dataset=data, split="train", num_envs=3,
                         keep_trajectories=0, progress=False, torch_threads=1)
        records = [r for d in ("easy", "medium") for r in run_evaluation(
            replace(cfg, difficulty=d), load_dataset(cfg)).records]
        assert row["sr"] == sr_interval(records)[0], path.name
        assert f"{path.name}: SR {row['sr']:.3f}" in printed
    srs = [row["sr"] for row in picked["picked_from"]]
    best = 1 if srs[1] >= srs[0] else 0  # ties: the later
    assert f"picked {paths[best].name}" in printed
    source = _params(paths[best])
    assert all(torch.equal(v, source[k]) for k, v in picked["model"].items())
    assert picked["agent_steps"] == load_checkpoint(paths[best])["agent_steps"]
    # val episodes are refused: picking on them would choose on the reported episodes
    val = tmp_path / "val_eps"
    assert main(["dataset", "generate", "--task", "commongoal", "--agents", "2", "--split",
                 "val", "--episodes", "1", "--scenes", "procedural:0", "--out", str(val),
                 "--quiet"]) == 0
    capsys.readouterr()
    assert main(["pick", str(root / "straight"), "--dataset", str(val), "--out",
                 str(tmp_path / "no.pt")]) == 2
    assert "holds no train-split episodes" in capsys.readouterr().err
    assert not (tmp_path / "no.pt").exists()


def test_run_directory_holds_config_and_tensorboard(resumed_and_straight):
    cfg, root, *_ = resumed_and_straight
    saved = json.loads((root / "straight" / "config.json").read_text())
    assert saved["method"] == "ours" and saved["model"]["comm"]["variant"] == "memory"
    assert saved["ppo"]["rollout_steps"] == cfg.ppo.rollout_steps
    assert any(p.name.startswith("events.out.tfevents") for p in (root / "straight").iterdir())


def test_resume_with_another_config_is_refused(resumed_and_straight):
    cfg, root, *_ = resumed_and_straight
    other = replace(cfg, ppo=replace(cfg.ppo, lr=1.0)).with_run(out=str(root / "straight"),
                                                                 resume=True)
    with pytest.raises(CheckpointError, match=r"different configuration.*ppo\.lr"):
        train(other)


def test_resume_from_refuses_what_it_cannot_continue(resumed_and_straight, tmp_path):
    from collavn.cli.train import resume_args
    from collavn.errors import ConfigError

    cfg, root, *_ = resumed_and_straight
    source = str(root / "straight" / CHECKPOINT)
    with pytest.raises(CheckpointError, match=r"--resume-from: no checkpoint at"):
        train(cfg.with_run(out=str(tmp_path / "a"), resume_from=str(tmp_path / "none.pt")))
    other = replace(cfg, ppo=replace(cfg.ppo, lr=1.0))
    with pytest.raises(CheckpointError, match=r"different configuration.*ppo\.lr"):
        train(other.with_run(out=str(tmp_path / "b"), resume_from=source))
    with pytest.raises(ConfigError, match="--resume and --resume-from exclude each other"):
        cfg.with_run(out=str(tmp_path / "c"), resume=True, resume_from=source)
    with pytest.raises(ConfigError, match="lies inside --out"):
        cfg.with_run(out=str(root / "straight"), resume_from=source)
    assert resume_args(["--out", "x", "--resume-from", source, "--seed", "2"]) == [
        "--out", "x", "--seed", "2", "--resume"]
    assert resume_args(["--overwrite", f"--resume-from={source}"]) == ["--resume"]


def test_checkpoint_loads_as_an_evaluation_policy_for_any_n(resumed_and_straight):
    _, root, *_ = resumed_and_straight
    policy, overrides = load_policy(root / "straight" / CHECKPOINT)
    assert overrides == {"panorama_width": 64, "panorama_height": 16, "goal_size": 16,
                         "free_space": 16}
    rng = np.random.default_rng(0)
    for n in (2, 3):
        obs = {"panorama": rng.integers(0, 255, (1, n, 3, 16, 64), dtype=np.uint8),
               "goal": rng.integers(0, 255, (1, n, 3, 16, 16), dtype=np.uint8),
               "pose_delta": np.zeros((1, n, 3), np.float32),
               "free_space": rng.uniform(0, 4, (1, n, 16)).astype(np.float32),
               "active": np.ones((1, n), bool), "step": np.zeros((1, n), np.int64),
           "episode_seed": np.zeros(1, np.int64)}
        state = policy.initial_state(1, n)
        a1, state = policy.act(obs, state)
        a2, _ = policy.act(obs, policy.initial_state(1, n))
        assert a1.shape == (1, n, 2) and np.all(np.abs(a1) <= 1.0)
        np.testing.assert_array_equal(a1, a2)  # deterministic


def test_init_from_loads_weights_and_refuses_another_model(resumed_and_straight):
    from collavn.training.distributed import DistInfo
    from collavn.training.trainer import build_run

    cfg, root, *_ = resumed_and_straight
    source = root / "straight" / CHECKPOINT
    run = build_run(cfg.with_run(init_from=str(source)), DistInfo(), torch.device("cpu"))
    for name, value in run.model.state_dict().items():
        torch.testing.assert_close(value, _params(source)[name], rtol=0, atol=0)
    other = replace(cfg, model=replace(cfg.model, hidden_size=cfg.model.hidden_size * 2)
                    ).with_run(init_from=str(source))
    with pytest.raises(CheckpointError, match=r"model config differs.*hidden_size"):
        build_run(other, DistInfo(), torch.device("cpu"))
    # Only the model config is compared: a checkpoint written before a training option
    # existed (here ``imitation.expert``) still starts a run.
    payload = load_checkpoint(source)
    del payload["config"]["imitation"]["expert"]
    older = save_checkpoint(root / "older.pt", payload)
    run = build_run(cfg.with_run(init_from=str(older)), DistInfo(), torch.device("cpu"))
    for name, value in run.model.state_dict().items():
        torch.testing.assert_close(value, _params(source)[name], rtol=0, atol=0)


def test_stochastic_evaluation_samples_reproducibly_and_leaves_torch_rng_alone(
        resumed_and_straight):
    _, root, *_ = resumed_and_straight
    rng = np.random.default_rng(1)
    obs = {"panorama": rng.integers(0, 255, (1, 2, 3, 16, 64), dtype=np.uint8),
           "goal": rng.integers(0, 255, (1, 2, 3, 16, 16), dtype=np.uint8),
           "pose_delta": np.zeros((1, 2, 3), np.float32),
           "free_space": rng.uniform(0, 4, (1, 2, 16)).astype(np.float32),
           "active": np.ones((1, 2), bool), "step": np.zeros((1, 2), np.int64),
           "episode_seed": np.zeros(1, np.int64)}
    mean_policy, _ = load_policy(root / "straight" / CHECKPOINT)
    mean, _ = mean_policy.act(obs, mean_policy.initial_state(1, 2))
    draws = []
    for _ in range(2):
        policy, _ = load_policy(root / "straight" / CHECKPOINT, stochastic=True, seed=5)
        torch.manual_seed(123)
        a, _ = policy.act(obs, policy.initial_state(1, 2))
        after = torch.rand(1)
        torch.manual_seed(123)
        assert torch.equal(after, torch.rand(1))  # the caller's random state is untouched
        draws.append(a)
    np.testing.assert_array_equal(draws[0], draws[1])
    assert not np.array_equal(draws[0], mean)


def test_init_from_a_silent_checkpoint_starts_a_talking_run_with_its_policy(tmp_path):
    """il / no-com → ours: the message inputs start at zero, so the first policy agrees."""
    from collavn.training.distributed import DistInfo
    from collavn.training.trainer import build_run, checkpoint_payload, message_weight

    silent = build_run(tiny_config("no-com", out=str(tmp_path / "a")), DistInfo(),
                       torch.device("cpu"))
    with torch.no_grad():  # non-zero weights everywhere the message could hide
        for p in silent.model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    source = save_checkpoint(tmp_path / "silent.pt", checkpoint_payload(silent))
    cfg = tiny_config("ours", out=str(tmp_path / "b")).with_run(init_from=str(source))
    talking = build_run(cfg, DistInfo(), torch.device("cpu"))
    tower = talking.model.towers[0]
    assert tower.comm is not None
    msg = tower.comm.output_size
    cut = tower.embed_size + tower.map_vector_size
    assert not tower.actor_core.weight_ih[:, cut:cut + msg].any()
    weights = message_weight(talking.model)  # the logged weight of ω: none yet, both cores
    assert weights["comm/actor_message_weight"] == weights["comm/critic_message_weight"] == 0.0
    torch.manual_seed(0)
    e, n = 2, 2
    obs = {"panorama": torch.randint(0, 255, (e, n, 3, 16, 64), dtype=torch.uint8),
           "goal": torch.randint(0, 255, (e, n, 3, 16, 16), dtype=torch.uint8),
           "pose_delta": torch.zeros(e, n, 3), "free_space": torch.rand(e, n, 16) * 4,
           "active": torch.ones(e, n, dtype=torch.bool)}
    start = torch.ones(e, n, dtype=torch.bool)
    for model in (silent.model, talking.model):
        model.eval()
    a = silent.model(obs, silent.model.initial_state(e, n), start)
    b = talking.model(obs, talking.model.initial_state(e, n), start)
    assert b.message.omega.abs().sum() > 0  # the message is there, with zero weight
    torch.testing.assert_close(b.dist.mean, a.dist.mean, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(b.value, a.value, rtol=1e-5, atol=1e-6)
    other = tiny_config("ours", out=str(tmp_path / "c")).with_run(init_from=str(source))
    other = replace(other, model=replace(other.model, hidden_size=64))
    with pytest.raises(CheckpointError, match="hidden_size"):
        build_run(other, DistInfo(), torch.device("cpu"))


def test_a_checkpoint_from_before_the_readout_loads_with_it_off(tmp_path):
    from collavn.models.config import ReadoutConfig
    from collavn.models.policy import ActorCritic

    cfg = tiny_config("no-com")
    model_cfg = replace(cfg.model, readout=ReadoutConfig(), free_space_input=0)
    config = replace(cfg, model=model_cfg).to_dict()
    del config["model"]["readout"]  # written before these fields existed
    del config["ppo"]["target_kl"]
    del config["model"]["free_space_input"]
    del config["model"]["goal_belief"]
    del config["imitation"]["belief_coef"]
    del config["ppo"]["bc_target"]
    del config["ppo"]["bc_steps"]
    del config["ppo"]["bc_blocked_window"]
    save_checkpoint(tmp_path / "old.pt", {"config": config, "update": 0,
                                          "model": ActorCritic(model_cfg).state_dict()})
    policy, _ = load_policy(tmp_path / "old.pt")
    assert policy.model.cfg.readout == ReadoutConfig(enabled=False)
    assert policy.model.towers[0].readout is None
    assert policy.model.cfg.free_space_input == 0
    assert policy.model.cfg.goal_belief == 0 and policy.model.towers[0].goal_belief is None
    old = saved_config(load_checkpoint(tmp_path / "old.pt"), "old.pt")
    assert old.ppo.target_kl == 0.0 and old.imitation.belief_coef == 1.0
    assert old.ppo.bc_target == "expert" and old.ppo.bc_steps == "all"
    assert old.ppo.bc_blocked_window == 3
    # one from before the ring readout had the pooled heads
    config = cfg.to_dict()
    del config["model"]["readout"]["ring"]
    save_checkpoint(tmp_path / "pooled.pt", {"config": config, "update": 0,
                                             "model": ActorCritic(cfg.model).state_dict()})
    policy, _ = load_policy(tmp_path / "pooled.pt")
    assert policy.model.cfg.readout == replace(cfg.model.readout, ring=False)
    assert type(policy.model.towers[0].readout).__name__ == "PerceptionReadout"
