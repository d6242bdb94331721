"""Perception pretraining: labels against the geodesic field, the loss falls on a tiny
set, and a training run's encoder is frozen, stored per step and size-checked."""

from __future__ import annotations

import dataclasses
import signal

import numpy as np
import pytest
import torch

from collavn.errors import CheckpointError, ConfigError
from collavn.models.config import MatchConfig, ReadoutConfig
from collavn.models.frames import FRAME_MODULES, FramePerception
from collavn.models.policy import MAP_TRACK
from collavn.perception.config import PerceptionConfig, PretrainConfig
from collavn.perception.encoder import encoder_spec, load_encoder, save_encoder
from collavn.perception.frames import render_frames, sample_batch
from collavn.perception.labels import column_of, free_space, goal_columns, path_columns
from collavn.perception.pretrain import Pretrainer
from collavn.training.distributed import DistInfo
from collavn.training.trainer import build_run, collect_rollout, learn, sync_point
from training_fixtures import TINY_MODEL, tiny_config

W = 64
#: TINY_MODEL with the rotation-equivariant readout.
RING_MODEL = dataclasses.replace(TINY_MODEL, readout=dataclasses.replace(TINY_MODEL.readout,
                                                                         ring=True))
DEPTH_MODEL = dataclasses.replace(TINY_MODEL, frame_depth=True)


def circular_gap(a, b, width=W):
    """Distance between columns around the panorama."""
    d = np.mod(np.asarray(a) - np.asarray(b), width)
    return np.minimum(d, width - d)


def test_labels_agree_with_the_geodesic_field_on_hand_picked_poses(l_corridor):
    # L corridor: x ∈ [0, 2] for all y, and y ∈ [0, 2] for all x; goal at its far end.
    goal = np.array([8.0, 1.0])
    field = l_corridor.geodesic_field(goal)
    pos = np.array([[1.0, 8.0], [1.0, 1.0], [5.0, 1.0]])
    yaw = np.array([0.0, np.pi / 2, np.pi])
    # (1, 8) facing +x: the path leaves down the corridor (−y, to the right); the goal
    # itself lies at −45°. (1, 1) facing +y: the goal (+x) is to the right. (5, 1) facing
    # −x: the goal is straight behind.
    path = path_columns(field, pos, yaw, W)
    expected = [column_of(-np.pi / 2, W), column_of(-np.pi / 2, W), column_of(np.pi, W)]
    assert (circular_gap(path, expected) <= W / 72 + 1e-9).all()  # 5° ring resolution
    np.testing.assert_allclose(goal_columns(pos, yaw, goal, W),
                               [column_of(-np.pi / 4, W), 3 * W / 4, 0.0], atol=1e-9)
    d = field.distance(pos)
    assert 11.0 < d[0] < 14.0 and d[2] == pytest.approx(3.0, abs=0.15)
    # turning left by k columns' worth moves the labels k columns right
    k = 5
    turned = path_columns(field, pos, yaw + 2 * np.pi * k / W, W)
    assert (circular_gap(turned - path, k) <= W / 72 + 1e-6).all()
    # free space: in the 2 m corridor facing +x at (1, 5) the wall is 1 m ahead, less the
    # robot's radius; along the corridor (+y, column W/4) more than the 4 m cap
    free = free_space(l_corridor.nav, np.array([[1.0, 5.0]]), np.array([0.0]), W, 4.0)[0]
    ahead, left = free[W // 2], free[W // 4]
    assert 0.6 <= ahead <= 0.85 and left == 4.0


def _tiny_pretrain(scene, model=TINY_MODEL) -> tuple[PretrainConfig, Pretrainer]:
    cfg = tiny_config("no-com", model=model)
    p = PerceptionConfig(frames_per_scene=24, goals_per_scene=3, val_frames_per_scene=8,
                         bins=8, batch_size=16, lr=3e-3, hidden=32, steps=80)
    pcfg = PretrainConfig(env=cfg.env, model=cfg.model, perception=p, progress=False)
    rng = np.random.default_rng(0)
    train = render_frames([scene], cfg.env, p, p.frames_per_scene, rng,
                          depth=model.frame_depth)
    val = render_frames([scene], cfg.env, p, p.val_frames_per_scene, rng,
                        depth=model.frame_depth)
    return pcfg, Pretrainer(pcfg, train, val)


def test_frames_are_labelled_by_the_scene(l_corridor):
    torch.set_num_threads(1)
    cfg, trainer = _tiny_pretrain(l_corridor)
    frames = trainer.train
    assert frames.panoramas.shape == (24, 3, 16, 64) and frames.goals.shape == (3, 3, 16, 16)
    assert np.isfinite(frames.distance).all()  # one connected corridor
    batch = sample_batch(frames, 32, cfg.perception, np.random.default_rng(1))
    assert batch["panorama"].shape == (32, 3, 16, 64) and batch["free"].shape == (32, 64)
    assert ((batch["path_column"] >= 0) & (batch["path_column"] < 64)).all()


@pytest.mark.parametrize("model", [TINY_MODEL, RING_MODEL, DEPTH_MODEL],
                         ids=["pooled", "ring", "depth"])
def test_pretraining_lowers_the_loss_on_a_tiny_set(l_corridor, model):
    torch.set_num_threads(1)
    cfg, trainer = _tiny_pretrain(l_corridor, model)
    fixed = sample_batch(trainer.train, 64, cfg.perception, np.random.default_rng(3),
                         augment=False)
    assert ("depth" in fixed) == model.frame_depth
    with torch.no_grad():
        before = float(trainer.loss(fixed)[0])
    for _ in range(cfg.perception.steps):
        trainer.step()
    with torch.no_grad():
        after = float(trainer.loss(fixed)[0])
    assert after < before - 0.4
    metrics = trainer.evaluate(pairs=32)
    for label in ("path_bearing", "goal_bearing", "distance", "free_space"):
        assert 0.0 <= metrics[f"val/{label}_accuracy"] <= 1.0


def test_depth_turns_with_the_panorama_and_is_read_only_when_asked(l_corridor):
    """``model.frame_depth``: a batch's depth is rolled and mirrored with its panorama;
    the panorama encoder reads it (other depth, other ``o``) and names the missing
    sensor when there is none; the goal matcher and the goal embedding ignore it."""
    torch.set_num_threads(1)
    cfg, trainer = _tiny_pretrain(l_corridor, DEPTH_MODEL)
    frames = trainer.train
    assert frames.depths is not None and frames.depths.shape == (24, 16, 64)
    assert np.isfinite(frames.depths).all() and frames.depths.max() > 1.0
    # a depth that *is* the panorama's red channel must still be after the augmentation
    red = dataclasses.replace(frames, depths=frames.panoramas[:, 0].astype(np.float16))
    batch = sample_batch(red, 64, cfg.perception, np.random.default_rng(5))
    assert np.array_equal(batch["depth"], batch["panorama"][:, 0].astype(np.float32))
    pan, goal = (torch.as_tensor(batch[k][:4]) for k in ("panorama", "goal"))
    depth = torch.as_tensor(sample_batch(frames, 4, cfg.perception,
                                         np.random.default_rng(5), False)["depth"])
    assert cfg.model.frame_depth
    net = FramePerception(cfg.model).eval()
    plain = FramePerception(dataclasses.replace(cfg.model, frame_depth=False)).eval()
    with torch.no_grad():
        o, g = net.see(pan, goal, depth)
        o2, g2 = net.see(pan, goal, depth + 1.0)
        plain_o, _ = plain.see(pan, goal)
    assert not torch.allclose(o, o2)
    # the goal embedding and the match vector do not read depth (the readout reads o)
    assert torch.equal(g[:, :net.pair_goal_size], g2[:, :net.pair_goal_size])
    assert o.shape == plain_o.shape
    with pytest.raises(ValueError, match=r"ModelConfig\.frame_depth.*EnvConfig\(depth=True\)"):
        net.see(pan, goal)
    with pytest.raises(ValueError, match=r"depth \(4, 64, 16\) does not fit the panorama"):
        net.see(pan, goal, depth.transpose(1, 2))
    from collavn.policies.adapter import env_overrides, policy_keys

    assert "depth" in policy_keys(DEPTH_MODEL) and "depth" not in policy_keys(TINY_MODEL)
    assert env_overrides(DEPTH_MODEL)["depth"] is True


def test_held_out_accuracy_is_scored_per_episode_difficulty(l_corridor, monkeypatch):
    """A perception right only from 3 m on scores 0 at easy distances, 1 at medium ones.

    One right only from 1.5 m on is partly right in the homing band (1–2 m).
    """
    import collavn.perception.pretrain as pretrain_module

    torch.set_num_threads(1)
    _, trainer = _tiny_pretrain(l_corridor, TINY_MODEL)

    def right_from_3m(pred, target):
        far = torch.expm1(target["distance"]) >= 3.0
        return {k: far for k in pretrain_module.PAIR_LABELS}

    monkeypatch.setattr(pretrain_module, "pair_hits", right_from_3m)
    metrics = trainer.evaluate(pairs=256)
    for label in pretrain_module.PAIR_LABELS:
        assert metrics[f"val/{label}_accuracy_easy"] == 0.0
        assert metrics[f"val/{label}_accuracy_medium"] == 1.0
    assert "val/free_space_accuracy_easy" not in metrics  # not a pair label
    assert metrics["val/path_bearing_accuracy_homing"] == 0.0

    def right_from_1_5m(pred, target):
        return {k: torch.expm1(target["distance"]) >= 1.5 for k in pretrain_module.PAIR_LABELS}

    monkeypatch.setattr(pretrain_module, "pair_hits", right_from_1_5m)
    metrics = trainer.evaluate(pairs=256)
    assert 0.0 < metrics["val/path_bearing_accuracy_homing"] < 1.0
    assert metrics["val/path_bearing_accuracy_easy"] == 1.0


def _encoder_file(tmp_path, model=TINY_MODEL, env=None):
    env = env or tiny_config().env
    model = dataclasses.replace(model, panorama_shape=(3, env.panorama_height,
                                                       env.panorama_width),
                                goal_shape=(3, env.goal_size, env.goal_size))
    torch.manual_seed(7)
    frames = FramePerception(model)
    path = save_encoder(tmp_path / "encoder.pt", frames,
                        encoder_spec(model, env.camera_height), {}, {}, 0)
    return path, frames


@pytest.mark.parametrize("method,model", [("ours", TINY_MODEL), ("il", TINY_MODEL),
                                          ("ours", DEPTH_MODEL)],
                         ids=["ours", "il", "ours-depth"])
def test_a_frozen_encoder_runs_once_per_step_and_stays_bit_identical(tmp_path, method,
                                                                     model):
    torch.set_num_threads(1)
    path, frames = _encoder_file(tmp_path, model)
    cfg = tiny_config(method, rollout_steps=5, model=model).with_run(encoder=str(path))
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    assert run.cfg.run.encoder_sha256 == load_encoder(path).sha256  # resume checks it
    tower = run.model.towers[0]
    saved = frames.frame_state_dict()
    assert all(torch.equal(v, tower.state_dict()[k]) for k, v in saved.items())
    trained = {id(p) for g in run.optimizer.param_groups for p in g["params"]}
    assert tower.readout is not None  # the pretrained heads are frozen with the encoder
    frozen = [p for m in tower.frame_modules() for p in m.parameters()]
    assert frozen and not any(p.requires_grad or id(p) in trained for p in frozen)
    sync_point(run)
    rollout, _ = collect_rollout(run)
    # the images are not kept: the update reads the stored features only
    assert "panorama" not in rollout.obs and "goal" not in rollout.obs
    assert "depth" not in rollout.obs  # the frame perception's depth is in its features
    assert {"o", "g", "map_hidden", *MAP_TRACK} == set(rollout.percepts)
    if method == "ours":
        # recomputed from the stored features, PPO's first-epoch log-probs are exact
        with torch.no_grad():
            out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                             rollout.episode_start, rollout.raw_actions,
                                             rollout.percepts)
        assert torch.equal(out.log_prob, rollout.log_probs)
        # the value to rounding: ≤ 1e-7 on AVX-512 CPUs (see test_training's replay test)
        torch.testing.assert_close(out.value, rollout.values, rtol=0, atol=1e-6)
    before = {n: p.detach().clone() for n, p in run.model.named_parameters()}
    learn(run, rollout)
    for name, p in run.model.named_parameters():
        moved = not torch.equal(p.detach(), before[name])
        if name.split(".")[2] in FRAME_MODULES:
            assert not moved, f"{name} changed"
    assert any(not torch.equal(p.detach(), before[n])
               for n, p in run.model.named_parameters() if "actor_core" in n)


def test_a_run_refuses_an_encoder_made_for_other_image_sizes(tmp_path):
    path, _ = _encoder_file(tmp_path)
    cfg = tiny_config("no-com").with_env(panorama_width=128, panorama_height=32)
    with pytest.raises(CheckpointError, match=r"pretrained on 3×16×64 panoramas and 16×16 "
                                              r"goal images; this run uses 3×32×128"):
        build_run(cfg.with_run(encoder=str(path)), DistInfo(), torch.device("cpu"))
    other = dataclasses.replace(TINY_MODEL, embed_dim=16)
    path, _ = _encoder_file(tmp_path, other)
    with pytest.raises(CheckpointError, match="embed_dim: encoder 16 vs run 32"):
        build_run(tiny_config("no-com").with_run(encoder=str(path)), DistInfo(),
                  torch.device("cpu"))
    with pytest.raises(CheckpointError, match="checksum"):
        build_run(tiny_config("no-com").with_run(encoder=str(path), encoder_sha256="ab" * 32),
                  DistInfo(), torch.device("cpu"))
    # an encoder pretrained without depth cannot feed a model whose encoder reads it
    path, _ = _encoder_file(tmp_path)
    with pytest.raises(CheckpointError, match=r"frame_depth: encoder null vs run true"):
        build_run(tiny_config("no-com", model=DEPTH_MODEL).with_run(encoder=str(path)),
                  DistInfo(), torch.device("cpu"))
    # an encoder pretrained without the readout heads cannot feed a model that reads them
    path, _ = _encoder_file(tmp_path, dataclasses.replace(TINY_MODEL, readout=ReadoutConfig()))
    with pytest.raises(CheckpointError, match=r"readout: encoder null vs run \{\"bins\": 8"):
        build_run(tiny_config("no-com").with_run(encoder=str(path)), DistInfo(),
                  torch.device("cpu"))


@pytest.mark.parametrize("model", [TINY_MODEL, RING_MODEL], ids=["pooled", "ring"])
def test_the_pretrained_heads_become_the_policy_readout(l_corridor, tmp_path, model):
    torch.set_num_threads(1)
    cfg, trainer = _tiny_pretrain(l_corridor, model)
    assert trainer.heads is trainer.frames.readout  # the model's own heads are trained
    for _ in range(3):
        trainer.step()
    trainer.frames.eval()
    path = save_encoder(tmp_path / "encoder.pt", trainer.frames,
                        encoder_spec(cfg.model, cfg.env.camera_height), {}, {}, 3)
    assert any(k.startswith("readout.") for k in load_encoder(path).state_dict)
    run = build_run(tiny_config("il", model=model).with_run(encoder=str(path)), DistInfo(),
                    torch.device("cpu"))
    tower = run.model.towers[0]
    assert type(tower.readout) is type(trainer.heads)
    batch = sample_batch(trainer.val, 4, cfg.perception, np.random.default_rng(0),
                         augment=False)
    pan, goal = torch.as_tensor(batch["panorama"]), torch.as_tensor(batch["goal"])
    k = cfg.perception.bins
    with torch.no_grad():
        _, g = tower.see(pan, goal)
        pred = trainer.heads(*trainer.frames.see_pair(pan, goal))
    assert g.shape == (4, tower.pair_goal_size + 3 * k + 1) and tower.goal_size == g.shape[1]
    readout = g[:, tower.pair_goal_size:]
    torch.testing.assert_close(readout[:, :k], pred["path_bearing"].softmax(-1))
    torch.testing.assert_close(readout[:, k:2 * k], pred["goal_bearing"].softmax(-1))
    torch.testing.assert_close(readout[:, 2 * k], pred["distance"])
    torch.testing.assert_close(readout[:, 2 * k + 1:], pred["free_space"])
    torch.testing.assert_close(readout[:, :k].sum(-1), torch.ones(4))


def test_pretraining_refuses_heads_of_another_size_than_the_models_readout():
    env = tiny_config().env
    with pytest.raises(ConfigError, match=r"model.readout \(bins 8, hidden 32\)"):
        PretrainConfig(env=env, model=TINY_MODEL, perception=PerceptionConfig(bins=16,
                                                                              hidden=32))


def test_the_ring_readout_turns_with_the_panorama():
    model = dataclasses.replace(RING_MODEL, panorama_shape=(3, 16, W), goal_shape=(3, 16, 16))
    torch.manual_seed(0)
    frames = FramePerception(model).eval()
    gen = torch.Generator().manual_seed(1)
    pan = torch.randint(0, 256, (3, 3, 16, W), generator=gen, dtype=torch.uint8)
    goal = torch.randint(0, 256, (3, 3, 16, 16), generator=gen, dtype=torch.uint8)
    sector = W // model.readout.bins
    with torch.no_grad():
        o, g, ring = frames.see_pair(pan, goal)
        _, _, turned = frames.see_pair(torch.roll(pan, sector, dims=-1), goal)
        torch.testing.assert_close(turned, torch.roll(ring, sector // 4, dims=-1))
        before, after = frames.readout(o, g, ring), frames.readout(o, g, turned)
    # the same weights judge every azimuth: with the same context, a panorama turned by
    # one sector turns every per-sector prediction by one sector
    for label in ("path_bearing", "goal_bearing", "free_space"):
        torch.testing.assert_close(after[label], torch.roll(before[label], 1, dims=-1))
        assert not torch.allclose(after[label], before[label])
    torch.testing.assert_close(after["distance"], before["distance"])


def test_the_goal_features_are_reused_only_while_goals_weights_and_modes_stay(monkeypatch):
    torch.manual_seed(0)
    frames = FramePerception(TINY_MODEL).eval()
    gen = torch.Generator().manual_seed(2)
    pan = torch.randint(0, 256, (4, *TINY_MODEL.panorama_shape), generator=gen,
                        dtype=torch.uint8)
    goals = torch.randint(0, 256, (4, *TINY_MODEL.goal_shape), generator=gen,
                          dtype=torch.uint8)
    computed = []
    real = frames._compute_goal_features
    monkeypatch.setattr(frames, "_compute_goal_features",
                        lambda goal: computed.append(goal.clone()) or real(goal))

    def see(goal):
        with torch.no_grad():
            o, g = frames.see(pan[:len(goal)], goal)
        with torch.enable_grad():  # the reference: no cache with gradients on
            ref = frames.see(pan[:len(goal)], goal)
        assert torch.equal(o, ref[0].detach()) and torch.equal(g, ref[1].detach())
        return g

    g0 = see(goals)
    assert len(computed) == 2  # the no-grad call filled the cache; the reference ran
    assert torch.equal(see(goals.clone()), g0) and len(computed) == 3  # a hit
    changed = goals.clone()
    changed[3, 1, 5, 7] ^= 1  # one new goal in one env: the whole batch is recomputed
    see(changed)
    assert len(computed) == 5 and torch.equal(computed[3], changed)
    with torch.no_grad():
        frames.goal_encoder.trunk[0].weight.mul_(1.5)  # any in-place change of a weight
    g1 = see(changed)
    assert len(computed) == 7 and not torch.equal(g1, g0)
    frames.load_state_dict(FramePerception(TINY_MODEL).state_dict())
    see(changed)
    assert len(computed) == 9
    see(changed[:2])  # another batch size
    assert len(computed) == 11
    frames.train()
    see(changed[:2])
    assert len(computed) == 12  # the small CNN has no batch norm or dropout: still a hit
    frames.goal_encoder.head.append(torch.nn.Dropout(0.0))  # a layer with a mode
    see(changed[:2])
    assert len(computed) == 14  # in training mode it is never reused
    frames.eval()  # the kept result is still that of these goals and weights
    see(changed[:2])
    assert len(computed) == 15


def test_the_ring_readout_refuses_what_it_cannot_read(tmp_path):
    with pytest.raises(ValueError, match=r"readout\.ring reads the goal matcher's"):
        dataclasses.replace(RING_MODEL, goal_match=MatchConfig(enabled=False))
    odd = dataclasses.replace(RING_MODEL, panorama_shape=(3, 16, W), goal_shape=(3, 16, 16),
                              readout=ReadoutConfig(enabled=True, bins=5, hidden=8, ring=True))
    with pytest.raises(ValueError, match=r"readout bins \(5\) must divide the matcher's 16"):
        FramePerception(odd)
    # an encoder pretrained with the pooled heads does not feed a ring model
    path, _ = _encoder_file(tmp_path, TINY_MODEL)
    with pytest.raises(CheckpointError, match=r"readout: encoder .* vs run .*\"ring\": true"):
        build_run(tiny_config("no-com", model=RING_MODEL).with_run(encoder=str(path)),
                  DistInfo(), torch.device("cpu"))


def test_free_space_is_a_policy_input_stored_with_the_rollout(tmp_path):
    from collavn.policies.checkpoint import load_policy, save_checkpoint

    torch.set_num_threads(1)
    path, _ = _encoder_file(tmp_path)
    model = dataclasses.replace(TINY_MODEL, free_space_input=8)
    cfg = tiny_config("ours", rollout_steps=3, model=model).with_run(encoder=str(path))
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    assert run.obs["free_space"].shape == (2, 2, 8)  # the run turned the sensor on
    tower = run.model.towers[0]
    assert tower.map_vector_size == cfg.model.map.embed_dim + 3 + 8
    rollout, _ = collect_rollout(run)
    assert rollout.obs["free_space"].shape == (3, 2, 2, 8)
    with torch.no_grad():
        out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                         rollout.episode_start, rollout.raw_actions,
                                         rollout.percepts)
        assert torch.equal(out.log_prob, rollout.log_probs)
        # the input matters: other free space, other actions
        blocked = dict(rollout.obs, free_space=torch.zeros_like(rollout.obs["free_space"]))
        other = run.model.evaluate_actions(blocked, rollout.initial_state,
                                           rollout.episode_start, rollout.raw_actions,
                                           rollout.percepts)
        assert not torch.equal(other.log_prob, rollout.log_probs)
        missing = {k: v for k, v in rollout.obs.items() if k != "free_space"}
        with pytest.raises(ValueError, match=r"reads 8 free-space directions; the "
                                             r"observation has None \(EnvConfig.free_space\)"):
            run.model.evaluate_actions(missing, rollout.initial_state, rollout.episode_start,
                                       rollout.raw_actions, rollout.percepts)
    save_checkpoint(tmp_path / "c.pt", {"config": cfg.to_dict(), "update": 0,
                                        "model": run.model.state_dict()})
    _, overrides = load_policy(tmp_path / "c.pt")
    assert overrides["free_space"] == 8  # evaluation renders what the policy reads


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_ends_pretraining_with_the_encoder_written(tmp_path, monkeypatch, capsys,
                                                            sig):
    """A killed ``collavn pretrain`` keeps its steps: the signal ends the loop after the
    step in progress, the held-out frames are scored, ``encoder.pt`` is written and the
    command exits 128 + signal."""
    import collavn.cli.pretrain as cli_pretrain
    import collavn.perception.pretrain as pretrain_module

    torch.set_num_threads(1)
    cfg = tiny_config("no-com")
    p = PerceptionConfig(frames_per_scene=8, goals_per_scene=2, val_frames_per_scene=4,
                         bins=8, batch_size=8, hidden=32, steps=50)
    pcfg = PretrainConfig(env=cfg.env, model=cfg.model, perception=p, progress=False,
                          out=str(tmp_path / "enc"), scenes=("procedural:0",),
                          val_scenes=("procedural:1",), eval_interval=1000)
    step = pretrain_module.Pretrainer.step
    calls = []

    def step_then_signal(self):
        calls.append(1)
        if len(calls) == 3:
            signal.raise_signal(sig)
        return step(self)

    monkeypatch.setattr(pretrain_module.Pretrainer, "step", step_then_signal)
    monkeypatch.setattr(cli_pretrain, "parse", lambda args, prog: pcfg)
    before = signal.getsignal(sig)
    assert cli_pretrain.main([]) == 128 + sig
    assert len(calls) == 3
    assert f"stopped by {sig.name} after 3 steps" in capsys.readouterr().out
    saved = torch.load(tmp_path / "enc" / "encoder.pt", weights_only=False)
    assert saved["steps"] == 3
    assert "val/path_bearing_accuracy" in load_encoder(tmp_path / "enc" / "encoder.pt").metrics
    assert signal.getsignal(sig) is before  # the run's handler is gone again


def test_the_held_out_frames_do_not_change_with_the_training_draw():
    """Encoders trained nearer their goals, or on more scenes, are scored on the same
    held-out frames and pairs: the val draw has its own random stream and the default
    ``near_distance`` / ``own_goal_fraction``, while the train draw follows the config."""
    from rich.progress import Progress

    from collavn.perception.pretrain import held_out_config, load_frames

    cfg = tiny_config("no-com")
    p = PerceptionConfig(frames_per_scene=6, goals_per_scene=2, val_frames_per_scene=4,
                         bins=8, batch_size=8, hidden=32)
    near = dataclasses.replace(p, near_distance=2.0, own_goal_fraction=1.0)
    sets = {}
    for name, perception in (("default", p), ("near", near)):
        pcfg = PretrainConfig(env=cfg.env, model=cfg.model, perception=perception,
                              progress=False, scenes=("procedural:0",),
                              val_scenes=("procedural:1",))
        with Progress(disable=True) as progress:
            sets[name] = load_frames(pcfg, progress)
    (train_a, val_a), (train_b, val_b) = sets["default"], sets["near"]
    assert np.array_equal(val_a.panoramas, val_b.panoramas)
    assert np.array_equal(val_a.distance, val_b.distance)
    assert not np.array_equal(train_a.panoramas, train_b.panoramas)
    # the near draw keeps its panoramas within 2 m of the goal it was sampled near
    own = train_b.distance[np.arange(len(train_b.distance)), train_b.own]
    assert (own <= 2.0 + 1e-6).all() and own.max() < train_a.distance.max()
    held = held_out_config(near)
    assert (held.near_distance, held.own_goal_fraction) == (10.0, 0.5)
    assert held.frames_per_scene == near.frames_per_scene
    # the held-out pairs too: the same weights score the same, whatever own_goal_fraction
    scores = []
    for perception in (p, near):
        pcfg = PretrainConfig(env=cfg.env, model=cfg.model, perception=perception,
                              progress=False)
        torch.manual_seed(0)
        scores.append(Pretrainer(pcfg, train_a, val_a).evaluate(pairs=64))
    assert scores[0] == scores[1]


def test_the_weight_average_is_what_pretraining_scores_and_saves(l_corridor, tmp_path,
                                                                 monkeypatch):
    """``perception.ema``: after n steps every averaged weight is the bias-corrected
    EMA Σ (1 − d) d^(n−i) w_i / (1 − d^n) of the weights after each step, and the raw
    weights are scored beside it."""
    torch.set_num_threads(1)
    cfg, base = _tiny_pretrain(l_corridor)
    d = 0.9
    pcfg = dataclasses.replace(cfg, perception=dataclasses.replace(cfg.perception, ema=d))
    trainer = Pretrainer(pcfg, base.train, base.val)
    history = []
    for _ in range(6):
        trainer.step()
        history.append({k: w.clone() for k, w in trainer.frames.state_dict().items()})
    n = len(history)
    expected = {k: sum((1 - d) * d ** (n - 1 - i) * h[k] for i, h in enumerate(history))
                / (1 - d ** n) for k in history[0]}
    frames, _ = trainer.modules_for()
    assert frames is not trainer.frames
    for k, a in frames.state_dict().items():
        torch.testing.assert_close(a, expected[k], rtol=1e-5, atol=1e-6)
    assert any(not torch.equal(a, trainer.frames.state_dict()[k])
               for k, a in frames.state_dict().items())
    averaged, raw = trainer.evaluate(pairs=32), trainer.evaluate(32, False, "val_raw")
    assert averaged["val/loss"] != raw["val_raw/loss"]
    with pytest.raises(ConfigError, match=r"perception\.ema"):
        PerceptionConfig(ema=1.0)
    # A whole run writes the average into encoder.pt and logs the raw scores beside it.
    import collavn.perception.pretrain as pretrain_module

    made = []
    monkeypatch.setattr(pretrain_module, "Pretrainer",
                        lambda *a: made.append(Pretrainer(*a)) or made[-1])
    run = dataclasses.replace(pcfg, out=str(tmp_path / "enc"), scenes=("procedural:0",),
                              val_scenes=("procedural:1",), eval_interval=1000,
                              perception=dataclasses.replace(pcfg.perception, steps=4))
    result = pretrain_module.pretrain(run)
    saved = load_encoder(result.path).state_dict
    average, raw = made[0].modules_for()[0], made[0].frames
    assert all(torch.equal(saved[k], v) for k, v in average.frame_state_dict().items())
    assert not all(torch.equal(saved[k], v) for k, v in raw.frame_state_dict().items())
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    logged = EventAccumulator(str(tmp_path / "enc"))
    logged.Reload()
    assert {"val/loss", "val_raw/loss"} <= set(logged.Tags()["scalars"])
