"""Bad input and faults: one-line errors, run directories, integrity checks, signals.

Every refused argument of every command ends in ``collavn: error: …`` (exit 2, no
traceback); damaged cache files are rebuilt, damaged checkpoints and relabelled
episodes refused; SIGINT/SIGTERM leave a checkpoint that resumes exactly; evaluation
results do not depend on ``--num-envs``.
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from collavn import configs
from collavn.cli import main
from collavn.datasets.episode import SceneRef
from collavn.datasets.generator import sample_episodes
from collavn.datasets.storage import (
    EpisodeFile,
    load_episode_file,
    save_episode_file,
)
from collavn.envs import EnvConfig
from collavn.errors import CheckpointError, DatasetError, SceneWarning
from collavn.evaluation.runner import evaluate
from collavn.files import atomic_write
from collavn.models.policy import ActorCritic
from collavn.policies import CheckpointPolicy, RandomPolicy
from collavn.policies.checkpoint import load_checkpoint, save_checkpoint
from collavn.scenes import load_scene
from collavn.training.presets import PRESETS
from collavn.training.trainer import CHECKPOINT, train
from training_fixtures import tiny_config

ROOT = Path(__file__).resolve().parents[1]
SMALL = EnvConfig(num_agents=2, panorama_width=32, panorama_height=8, goal_size=8)


# ----------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def files(tmp_path_factory, door_scene):
    """A dataset, a tiny checkpoint, a non-empty directory, a plain file, bad meshes."""
    root = tmp_path_factory.mktemp("probes")
    scene_file = root / "door.npz"
    door_scene.save(scene_file)
    assert main(["dataset", "generate", "--split", "test", "--episodes", "1", "--scenes",
                 str(scene_file), "--out", str(root / "data"), "--quiet"]) == 0
    cfg = tiny_config("no-com")
    torch.manual_seed(0)
    model = ActorCritic(cfg.model)
    good = {"config": cfg.to_dict(), "iteration": 0, "agent_steps": 0,
            "model": model.state_dict()}
    save_checkpoint(root / "good.pt", good)
    config = cfg.to_dict()
    del config["model"]["hidden_size"]
    broken = {**good, "config": config}
    save_checkpoint(root / "missing_key.pt", broken)
    nan = {k: v.clone() for k, v in model.state_dict().items()}
    next(v for v in nan.values() if v.is_floating_point()).view(-1)[0] = float("nan")
    save_checkpoint(root / "nan.pt", {**good, "model": nan})
    other = cfg.with_env(panorama_width=128, panorama_height=32)
    save_checkpoint(root / "other_size.pt", {**good, "config": other.to_dict()})
    flipped = bytearray((root / "good.pt").read_bytes())
    flipped[len(flipped) // 2] ^= 0x01
    (root / "flipped.pt").write_bytes(bytes(flipped))
    (root / "full").mkdir()
    (root / "full" / "old.txt").write_text("earlier results")
    (root / "plain").write_text("a file")
    box = trimesh.creation.box((8, 6, 0.1))
    for far in (2000.0, 1e30):
        stray = trimesh.Trimesh(box.vertices[:3] + [far, 0, 0], [[0, 1, 2]], process=False)
        trimesh.util.concatenate([box, stray]).export(root / f"stray{far:g}.ply")
    return root


def _probes(root: Path) -> list[tuple[list[str], str]]:
    """``(argv, words the error must contain)`` per bad argument or fault."""
    data, full, plain = str(root / "data"), str(root / "full"), str(root / "plain")
    ev = ["evaluate", "--dataset", data, "--out", str(root / "eval-new"), "--panorama-width",
          "32", "--panorama-height", "8", "--goal-size", "8"]
    return [
        (["train", "--checkpoint-interval", "0"], "--checkpoint-interval must be"),
        (["train", "--ppo.lr", "nan"], "--ppo.lr must be a finite number"),
        (["train", "--ppo.lr", "-1"], "--ppo.lr must be a finite number"),
        (["train", "--imitation.lr", "inf"], "--imitation.lr must be a finite"),
        (["train", "--total-steps", "0"], "--total-steps must be"),
        (["train", "--time-budget-minutes", "-1"], "--time-budget-minutes must be"),
        (["train", "--num-envs", "0"], "--num-envs must be"),
        (["train", "--train-scenes", "0"], "--train-scenes must be"),
        (["pretrain", "--perception.ema", "1"], "--perception.ema must be in [0, 1)"),
        (["train", "--agents", "0"], "--agents must be"),
        (["train", "--seed", "-1"], "--seed must be"),
        (["train", "--out", "/proc/foo"], "cannot write to --out /proc/foo"),
        (["train", "--out", plain], "is a file, not a directory"),
        (["train", "--out", full], "already holds results"),
        (["train", "--out", str(root / "typo"), "--resume"], "no checkpoint at"),
        (["train", "--out", full, "--resume", "--overwrite"], "exclude each other"),
        ([*ev, "--seed", "-1"], "--seed must be"),
        ([*ev, "--num-envs", "0"], "--num-envs must be"),
        (["evaluate", "--dataset", data, "--out", "/proc/foo"], "cannot write to --out"),
        (["evaluate", "--dataset", data, "--out", full], "already holds results"),
        ([*ev, "--policy", str(root / "flipped.pt")], "is damaged"),
        ([*ev, "--policy", str(root / "nan.pt")], "holds NaN or inf"),
        ([*ev, "--policy", str(root / "missing_key.pt")], "missing key model.hidden_size"),
        ([*ev, "--policy", str(root / "other_size.pt")], "do not fit its model config"),
        (["scene", "info", "procedural:0", "--map", "/proc/foo/map.png"],
         "cannot write --map /proc/foo/map.png"),
        (["scene", "info", str(root / "stray2000.ply")], "spans 2,00"),
        (["scene", "info", str(root / "stray1e+30.ply")], "spans 1e+30"),
        (["scene", "info", str(root / "stray2000.ply"), "--floor-height", "nan"],
         "floor_height must be a finite"),
        (["render", "procedural:0", "--width", "100000", "--height", "100000"],
         "more than the limit"),
        (["render", "procedural:0", "--width", "0"], "camera size must be positive"),
        (["render", "procedural:0", "--out", "/proc/foo/x.png"], "cannot write --out"),
        (["viz", str(root), "--gifs", "-1"], "--gifs must be"),
    ]


def test_every_bad_argument_gives_one_line_collavn_error(files, capsys):
    failures = []
    for argv, words in _probes(files):
        if (files / "eval-new").exists():  # a probe that wrongly ran must not block the next
            shutil.rmtree(files / "eval-new")
        try:
            rc = main(argv)
        except BaseException as e:
            failures.append(f"{argv}: raised {type(e).__name__}: {e}")
            continue
        err = capsys.readouterr().err.strip().splitlines()
        last = err[-1] if err else ""
        if rc != 2 or not last.startswith("collavn: error: ") or words not in last:
            failures.append(f"{argv}: rc {rc}, stderr {err[-3:]}")
    assert not failures, "\n".join(failures)
    assert sorted(p.name for p in (files / "full").iterdir()) == ["old.txt"]  # untouched


# --------------------------------------------------------------- integrity
def test_a_flipped_byte_in_a_scene_cache_file_is_rebuilt_with_a_warning(tmp_path):
    scene = load_scene("procedural:0", cache_dir=tmp_path)
    [cached] = tmp_path.glob("*.npz")
    data = bytearray(cached.read_bytes())
    data[len(data) // 2] ^= 0x10
    cached.write_bytes(bytes(data))
    with pytest.warns(SceneWarning, match="rebuilding the cached scene procedural:0"):
        again = load_scene("procedural:0", cache_dir=tmp_path)
    assert again.content_hash == scene.content_hash
    assert load_scene("procedural:0", cache_dir=tmp_path).content_hash == scene.content_hash


def test_a_flipped_bit_in_a_checkpoint_is_refused_and_stale_temp_files_cleaned(tmp_path):
    path = tmp_path / "ck.pt"
    save_checkpoint(path, {"model": {"w": torch.linspace(0, 1, 4096)}})
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x01
    path.write_bytes(bytes(data))
    with pytest.raises(CheckpointError, match=r"is damaged.*sha256"):
        load_checkpoint(path)
    (tmp_path / ".ck.pt.abc123.tmp").write_bytes(b"left by a kill mid-save")
    save_checkpoint(path, {"model": {"w": torch.zeros(3)}})
    assert sorted(os.listdir(tmp_path)) == ["ck.pt"]
    torch.save({"format": 2, "model": {"w": torch.ones(2)}}, tmp_path / "v2.pt")
    assert load_checkpoint(tmp_path / "v2.pt")["model"]["w"].tolist() == [1.0, 1.0]


def test_a_full_disk_while_saving_a_checkpoint_is_an_error_and_keeps_the_old_one(
        tmp_path, monkeypatch):
    path = tmp_path / "ck.pt"
    save_checkpoint(path, {"x": torch.arange(3)})

    def full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr("collavn.policies.checkpoint.atomic_write", full)
    with pytest.raises(CheckpointError, match=r"No space left.*unchanged"):
        save_checkpoint(path, {"x": torch.arange(5)})
    monkeypatch.undo()
    assert load_checkpoint(path)["x"].tolist() == [0, 1, 2]


def test_a_relabelled_rehashed_episode_is_refused_with_its_id(door_scene, tmp_path):
    [ep] = sample_episodes(door_scene, "commongoal", 2, "medium", 1,
                           np.random.default_rng(0))
    content = EpisodeFile("commongoal", 2, "val", SceneRef.of(door_scene), {"seed": 0},
                          (dataclasses.replace(ep, difficulty="easy"),))
    save_episode_file(tmp_path / "relabelled.json.gz", content)  # a valid hash again
    with pytest.raises(DatasetError, match=rf"episode {ep.episode_id} is labelled easy"):
        load_episode_file(tmp_path / "relabelled.json.gz")
    forged = dataclasses.replace(ep, difficulty="easy",
                                 start_distances=np.full(2, 2.0))
    save_episode_file(tmp_path / "forged.json.gz",
                      dataclasses.replace(content, episodes=(forged,)))
    load_episode_file(tmp_path / "forged.json.gz")  # consistent on its face...
    with pytest.raises(DatasetError, match=rf"episode {ep.episode_id}: stored start "
                                           r"distances 2\.00, 2\.00 m differ"):
        load_episode_file(tmp_path / "forged.json.gz", door_scene)  # ...not in its scene


def test_atomic_write_leaves_others_temp_files_unless_asked(tmp_path):
    (tmp_path / ".f.x.tmp").write_bytes(b"another writer's")
    atomic_write(tmp_path / "f", b"1")
    assert (tmp_path / ".f.x.tmp").exists()
    atomic_write(tmp_path / "f", b"2", clean_stale=True)
    assert sorted(os.listdir(tmp_path)) == ["f"]


# -------------------------------------------------------------- evaluation
@pytest.fixture(scope="module")
def episodes(door_scene):
    return sample_episodes(door_scene, "commongoal", 2, "easy", 5, np.random.default_rng(3))


def test_random_evaluation_does_not_depend_on_num_envs(door_scene, episodes):
    env = dataclasses.replace(SMALL, odometry_noise=0.05, max_steps=25)
    runs = [evaluate(RandomPolicy(7), door_scene, episodes, env, num_envs=k, seed=2).records
            for k in (1, 4)]
    assert runs[0] == runs[1]
    other = evaluate(RandomPolicy(8), door_scene, episodes, env, num_envs=4, seed=2).records
    assert other != runs[0]


def test_stochastic_checkpoint_evaluation_does_not_depend_on_num_envs(door_scene, episodes):
    # a silent policy: with communication on, blocks are exact only to ~1e-9 (known;
    # tests/test_evaluation.py::test_a_communicating_policy_scores_the_same_for_any_num_envs)
    cfg = tiny_config("no-com")
    env = dataclasses.replace(SMALL, panorama_width=64, panorama_height=16, goal_size=16,
                              max_steps=12, free_space=cfg.model.free_space_input)
    torch.manual_seed(0)
    model = ActorCritic(cfg.model)
    runs = [evaluate(CheckpointPolicy(model, stochastic=True, seed=4), door_scene,
                     episodes[:3], env, num_envs=k, seed=1).records for k in (1, 3)]
    assert runs[0] == runs[1]
    mean = evaluate(CheckpointPolicy(model), door_scene, episodes[:3], env, num_envs=3,
                    seed=1).records
    assert mean != runs[0]


def test_evaluate_refuses_a_used_out_unless_overwrite_and_moves_the_old_aside(
        files, tmp_path, capsys):
    out = tmp_path / "eval"
    base = ["evaluate", "--dataset", str(files / "data"), "--out", str(out), "--progress",
            "False", "--panorama-width", "32", "--panorama-height", "8", "--goal-size", "8"]
    base = [a for a in base if a not in ("--progress", "False")]
    assert main(base) == 0
    assert main(base) == 2
    assert "already holds results" in capsys.readouterr().err
    assert main([*base, "--overwrite"]) == 0
    [old] = tmp_path.glob("eval.old-*")
    assert (old / "records.jsonl").read_text() == (out / "records.jsonl").read_text()


# ------------------------------------------------------------------ signals
def cli_flags(cfg) -> list[str]:
    """``collavn train`` flags that turn the default preset into ``cfg``."""
    base = PRESETS["cpu"][1]
    derived = ("model.panorama_shape", "model.goal_shape", "model.comm.variant")
    flags = []
    for path, (_, value) in configs.differences(base.to_dict(), cfg.to_dict()).items():
        if path.startswith(derived):
            continue
        name = path.removeprefix("run.").replace("_", "-")
        if isinstance(value, bool):
            flags.append(f"--{name}" if value else f"--no-{name}" if "." not in name
                         else f"--{name.rsplit('.', 1)[0]}.no-{name.rsplit('.', 1)[1]}")
        elif isinstance(value, list):
            flags += [f"--{name}", *map(str, value)]
        else:
            flags += [f"--{name}", str(value)]
    return flags


UPDATES = 6


@pytest.fixture(scope="module")
def straight(tmp_path_factory):
    """The uninterrupted reference run, and its config."""
    cfg = tiny_config("no-com", out=str(tmp_path_factory.mktemp("sig") / "straight"))
    cfg = cfg.with_run(total_steps=UPDATES * 16)
    train(cfg)
    return cfg, load_checkpoint(Path(cfg.run.out) / CHECKPOINT)["model"]


def test_cli_flags_rebuild_the_tiny_config(straight):
    from collavn.cli.train import parse

    cfg, _ = straight
    assert parse(cli_flags(cfg)).to_dict() == cfg.to_dict()


def _interrupt(cfg, out: Path, signals: list[signal.Signals]) -> subprocess.CompletedProcess:
    """Start ``collavn train``; after its first checkpoint send ``signals``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src"), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "collavn.cli", "train", *cli_flags(cfg.with_run(out=str(out)))],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / CHECKPOINT).exists() and proc.poll() is None:
        assert time.monotonic() < deadline, "no checkpoint after 120 s"
        time.sleep(0.05)
    for s in signals:
        proc.send_signal(s)
        time.sleep(0.02)
    stdout, stderr = proc.communicate(timeout=120)
    return subprocess.CompletedProcess(proc.args, proc.returncode, stdout, stderr)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_stops_with_a_checkpoint_that_resumes_to_the_same_weights(
        straight, tmp_path, sig):
    cfg, reference = straight
    out = tmp_path / "run"
    done = _interrupt(cfg, out, [sig])
    assert done.returncode == 128 + sig, done.stderr
    assert "Traceback" not in done.stderr
    assert f"stopped by {sig.name}" in done.stderr and "--resume" in done.stderr
    stopped = load_checkpoint(out / CHECKPOINT)["iteration"]
    assert 0 < stopped < UPDATES and stopped % cfg.run.checkpoint_interval == 0
    train(cfg.with_run(out=str(out), resume=True))
    resumed = load_checkpoint(out / CHECKPOINT)["model"]
    for k in reference:
        assert torch.equal(reference[k], resumed[k]), k


def test_a_second_signal_stops_at_once_and_keeps_the_last_good_checkpoint(
        straight, tmp_path):
    cfg, _ = straight
    out = tmp_path / "run"
    done = _interrupt(cfg, out, [signal.SIGTERM, signal.SIGTERM])
    assert done.returncode == 143, done.stderr
    assert "Traceback" not in done.stderr and "without saving" in done.stderr
    assert not list(out.glob(".*.tmp"))
    stopped = load_checkpoint(out / CHECKPOINT)["iteration"]  # intact, at a sync point
    assert stopped % cfg.run.checkpoint_interval == 0


def test_overwrite_moves_the_old_run_aside(tmp_path):
    cfg = tiny_config("no-com", out=str(tmp_path / "run")).with_run(total_steps=16)
    train(cfg)
    result = train(cfg.with_run(overwrite=True))
    assert result.moved is not None and (result.moved / CHECKPOINT).is_file()
    assert result.moved.name.startswith("run.old-") and (tmp_path / "run" / CHECKPOINT).is_file()


@pytest.mark.parametrize("torch_first", [False, True])
def test_a_one_thread_run_stays_on_one_thread_whatever_ran_before(torch_first):
    """Numba's OpenMP layer resets the OpenMP thread count when it starts; torch's count
    must be set after it, or a run that follows any torch op runs on every core (and a
    resumed run rounds differently from an uninterrupted one)."""
    code = ("import torch\n"
            + ("torch.arange(3)\n" if torch_first else "")
            + "from collavn.threads import apply_threads\n"
              "apply_threads(1)\n"
              "print(torch.get_num_threads())\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS",
                                                             "MKL_NUM_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=env, check=True, timeout=120)
    assert out.stdout.strip() == "1"
