"""Training: GAE by hand, the loss goes down on a fixed batch, config and CLI resolution."""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
import torch

from collavn.cli.train import parse
from collavn.configs import join_docstring_lines
from collavn.errors import CollavnError, ConfigError
from collavn.training.config import RunConfig, TrainConfig
from collavn.training.distributed import DistInfo
from collavn.training.imitation import imitation_loss, imitation_update
from collavn.training.ppo import critic_parameters, ppo_loss, ppo_update
from collavn.training.presets import CPU_REASONS, preset_config, preset_deviations
from collavn.training.rollout import compute_gae
from collavn.training.trainer import (
    ActionTally,
    ScoreTally,
    build_run,
    collect_rollout,
    message_columns,
    message_weight,
    scene_window,
    sync_point,
)
from training_fixtures import tiny_config


def test_gae_hand_computed_with_termination_and_truncation():
    # One env, two agents, three steps. Agent 0 reaches its goal with action 1 (the
    # env then starts a new episode for it at step 2); agent 1 is truncated at step 2.
    g, lam = 0.9, 0.5
    rewards = torch.tensor([[[1.0, 0.5]], [[2.0, 0.0]], [[0.0, 1.0]]])
    values = torch.tensor([[[0.5, 1.0]], [[1.0, 2.0]], [[3.0, 4.0]]])
    terminated = torch.zeros(3, 1, 2, dtype=torch.bool)
    truncated = torch.zeros(3, 1, 2, dtype=torch.bool)
    terminated[1, 0, 0] = True
    truncated[2, 0, 1] = True
    last = torch.tensor([[10.0, 20.0]])
    adv, ret = compute_gae(rewards, values, terminated, truncated, last, g, lam)
    # Agent 0: t=2 is a new episode bootstrapped from last_value; t=1 terminal.
    a0_2 = 0.0 + g * 10.0 - 3.0                      # 6.0
    a0_1 = 2.0 - 1.0                                 # 1.0 (no bootstrap, chain cut)
    a0_0 = (1.0 + g * 1.0 - 0.5) + g * lam * a0_1    # 1.4 + 0.45 = 1.85
    # Agent 1: truncated at t=2 → bootstrap with its own value V(s_2) = 4.
    a1_2 = 1.0 + g * 4.0 - 4.0                       # 0.6
    a1_1 = (0.0 + g * 4.0 - 2.0) + g * lam * a1_2    # 1.6 + 0.27 = 1.87
    a1_0 = (0.5 + g * 2.0 - 1.0) + g * lam * a1_1    # 1.3 + 0.8415 = 2.1415
    expected = torch.tensor([[[a0_0, a1_0]], [[a0_1, a1_1]], [[a0_2, a1_2]]])
    assert torch.allclose(adv, expected, atol=1e-6)
    assert torch.allclose(ret, expected + values, atol=1e-6)


def test_gae_reduces_to_discounted_return_with_lambda_one():
    rewards = torch.ones(4, 1, 1)
    values = torch.zeros(4, 1, 1)
    none = torch.zeros(4, 1, 1, dtype=torch.bool)
    adv, _ = compute_gae(rewards, values, none, none, torch.zeros(1, 1), 0.5, 1.0)
    assert adv.flatten().tolist() == pytest.approx([1.875, 1.75, 1.5, 1.0])


def test_presets_keep_paper_values_and_cli_overrides():
    paper = preset_config("paper", method="no-mem")
    assert (paper.ppo.num_minibatches, paper.ppo.update_epochs) == (5, 8)
    assert (paper.ppo.lr, paper.ppo.ent_coef, paper.ppo.vf_coef, paper.ppo.gamma) == (
        1e-5, 0.001, 0.5, 0.99)
    assert paper.run.num_envs == 25 and paper.model.encoder == "resnet18"
    assert (paper.mapping.fifo_size, paper.mapping.updates, paper.mapping.batch_size) == (
        5000, 10, 64)
    assert paper.model.comm.variant == "handshake"
    assert paper.model.panorama_shape == (3, 128, 512)
    cfg = parse(["--method", "no-com", "--preset", "cpu", "--ppo.lr", "1e-3", "--num-envs",
                 "3", "--out", "x", "--ppo.clip-coef", "0.1", "--ppo.ent-coef", "0.01",
                 "--ppo.gae-lambda", "0.9", "--model.hidden-size", "64", "--agents", "3"])
    assert cfg.ppo.lr == 1e-3 and cfg.run.num_envs == 3 and cfg.model.comm.variant == "none"
    assert (cfg.ppo.clip_coef, cfg.ppo.ent_coef, cfg.ppo.gae_lambda) == (0.1, 0.01, 0.9)
    assert cfg.model.hidden_size == 64 and cfg.env.num_agents == 3
    assert cfg.model.panorama_shape == (3, cfg.env.panorama_height, cfg.env.panorama_width)
    assert cfg.preset == "cpu" and cfg.model.encoder == "small"
    assert TrainConfig.from_dict(cfg.to_dict()) == cfg
    # the image sizes are stated once (env); the model's shapes follow them
    small = cfg.with_env(panorama_width=64, panorama_height=16)
    assert small.model.panorama_shape == (3, 16, 64)


def test_saved_config_round_trips_exactly_and_refuses_unknown_or_missing_keys(tmp_path):
    import json

    for name in ("paper", "cpu"):
        cfg = preset_config(name, method="il")
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps(cfg.to_dict()))
        assert TrainConfig.from_dict(json.loads(path.read_text())) == cfg
    d = preset_config("cpu").to_dict()
    d["ppo"]["clip_coeff"] = 0.1
    with pytest.raises(ConfigError, match=r"unknown config key ppo\.clip_coeff"):
        TrainConfig.from_dict(d)
    d = preset_config("cpu").to_dict()
    del d["model"]["map"]["hidden"]
    with pytest.raises(ConfigError, match=r"missing key model\.map\.hidden"):
        TrainConfig.from_dict(d)


def test_a_config_written_before_a_later_field_loads_with_that_fields_old_behaviour():
    """``model.comm.listen`` came after checkpoints were written: absent, it is True (as
    they ran); given, it is kept; other missing keys are still refused."""
    cfg = preset_config("cpu", method="ours")
    d = cfg.to_dict()
    del d["model"]["comm"]["listen"]
    assert TrainConfig.from_dict(d) == cfg and cfg.model.comm.listen
    deaf = TrainConfig.from_dict(cfg.to_dict() | {"model": {
        **cfg.to_dict()["model"], "comm": {**d["model"]["comm"], "listen": False}}})
    assert not deaf.model.comm.listen
    del d["model"]["comm"]["temperature"]
    with pytest.raises(ConfigError, match=r"missing key model\.comm\.temperature"):
        TrainConfig.from_dict(d)


def test_no_listen_needs_a_method_with_messages():
    from collavn.models.config import CommConfig

    for method in ("no-com", "il"):
        cfg = preset_config("cpu", method=method)
        with pytest.raises(ConfigError, match=r"no-listen.*has none"):
            dataclasses.replace(cfg, model=dataclasses.replace(cfg.model,
                                                               comm=CommConfig(listen=False)))
    ours = preset_config("cpu", method="ours")
    comm = dataclasses.replace(ours.model.comm, listen=False)
    deaf = dataclasses.replace(ours, model=dataclasses.replace(ours.model, comm=comm))
    assert not deaf.model.comm.listen and deaf.model.comm.variant == "memory"
    with pytest.raises(ConfigError, match=r"message-floor.*no-listen cuts every link"):
        dataclasses.replace(deaf, ppo=dataclasses.replace(deaf.ppo, message_floor=0.25))


@pytest.mark.parametrize("who", ["critic", "actor"])
def test_no_critic_or_actor_hears_needs_a_listening_method_with_messages(who):
    from collavn.models.config import CommConfig

    field = f"{who}_hears"
    for method in ("no-com", "il"):
        cfg = preset_config("cpu", method=method)
        with pytest.raises(ConfigError, match=rf"no-{who}-hears.*has none"):
            dataclasses.replace(cfg, model=dataclasses.replace(
                cfg.model, comm=CommConfig(**{field: False})))
    ours = preset_config("cpu", method="ours")
    d = ours.to_dict()
    del d["model"]["comm"][field]  # written before the field: both hear
    assert TrainConfig.from_dict(d) == ours and getattr(ours.model.comm, field)
    comm = dataclasses.replace(ours.model.comm, **{field: False})
    half = dataclasses.replace(ours, model=dataclasses.replace(ours.model, comm=comm))
    assert TrainConfig.from_dict(half.to_dict()) == half
    with pytest.raises(ConfigError, match=rf"no-{who}-hears.*no-listen hears none"):
        dataclasses.replace(half, model=dataclasses.replace(
            half.model, comm=dataclasses.replace(comm, listen=False)))
    with pytest.raises(ConfigError, match=r"hears no teammate: that is --model.comm.no-l"):
        dataclasses.replace(half, model=dataclasses.replace(half.model, comm=dataclasses.replace(
            comm, critic_hears=False, actor_hears=False)))


def test_cpu_deviations_are_computed_and_every_one_has_a_reason():
    deviations = preset_deviations()
    missing = [path for path, (_, _, why) in deviations.items() if why is None]
    assert missing == []
    # a reason for a field that no longer differs is stale
    stale = [k for k in CPU_REASONS if not any(p == k or p.startswith(k + ".")
                                               for p in deviations)]
    assert stale == []
    assert deviations["ppo.lr"][:2] == (1e-5, 1e-3)
    assert deviations["model.comm.value_dim"][:2] == (2048, 256)
    assert "ppo.clip_coef" not in deviations
    # a new difference without a reason is reported as such
    assert preset_deviations(reasons={})["ppo.lr"][2] is None


def test_every_config_field_is_a_flag_with_a_docstring_in_help(capsys):
    with pytest.raises(SystemExit):
        parse(["--help"])
    text = capsys.readouterr().out
    for section in ("ppo", "mapping", "imitation"):
        for f in dataclasses.fields(getattr(preset_config("cpu"), section)):
            assert f"--{section}." + f.name.replace("_", "-") in text
    for f in dataclasses.fields(RunConfig):
        if f.name != "load":  # a nested section whose flags have no prefix
            assert "--" + f.name.replace("_", "-") in text
    for flag in ("--method", "--agents", "--task", "--panorama-width", "--env.difficulty",
                 "--up-axis", "--scale", "--floor-height",
                 "--model.hidden-size", "--model.comm.memory-slots"):
        assert flag in text
    assert "--model.panorama-shape" not in text  # derived from env, not a flag


def test_help_joins_a_docstring_s_source_lines(capsys, monkeypatch):
    monkeypatch.setenv("COLUMNS", "80")
    with pytest.raises(SystemExit):
        parse(["--help"])
    lines = capsys.readouterr().out.splitlines()
    for flag in ("--ppo.bc-coef FLOAT", "--ppo.start-std FLOAT"):
        start = next(i for i, ln in enumerate(lines) if flag in ln) + 1
        text = []
        for ln in lines[start:]:
            ln = ln.strip("│ ")  # a panel's borders, when the output is a terminal
            if not ln or ln.startswith("--") or "─" in ln:
                break
            text.append(ln)
        # wrapped by the terminal's width, not at the docstring's source line ends
        # (those left lines like "log-likelihood of" and "after")
        assert len(text) >= 4 and min(len(t) for t in text[:-1]) >= 45, text


def test_join_docstring_lines_keeps_paragraphs_and_list_items():
    doc = "First line\n    goes on.\n\n    Second paragraph:\n    - one\n      item\n    - two\n"
    assert join_docstring_lines(doc) == (
        "First line goes on.\n\nSecond paragraph:\n- one item\n- two")
    assert join_docstring_lines("one line") == "one line"


def _fixed_batch(method: str, num_envs: int = 2, **model):
    cfg = tiny_config(method=method, rollout_steps=6)
    cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, **model))
    cfg = cfg.with_run(num_envs=num_envs)
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    rollout, _ = collect_rollout(run)
    return cfg, run, rollout


def test_ppo_loss_goes_down_on_a_fixed_batch():
    cfg, run, rollout = _fixed_batch("ours")
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    ppo = dataclasses.replace(cfg.ppo, lr=1e-3, update_epochs=10, num_minibatches=1)
    before, _ = ppo_loss(run.model, rollout, adv, ret, ppo)
    ppo_update(run.model, run.optimizer, rollout, adv, ret, ppo, run.generator)
    for group in run.optimizer.param_groups:
        group["lr"] = 1e-3
    ppo_update(run.model, run.optimizer, rollout, adv, ret, ppo, run.generator)
    after, stats = ppo_loss(run.model, rollout, adv, ret, ppo)
    assert float(after.detach()) < float(before.detach()) - 1e-3
    assert np.isfinite(stats["approx_kl"])


def test_target_kl_stops_the_epochs_once_the_policy_has_moved():
    cfg, run, rollout = _fixed_batch("no-com")
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    for group in run.optimizer.param_groups:
        group["lr"] = 1e-2
    start = {n: p.detach().clone() for n, p in run.model.named_parameters()}
    full = ppo_update(run.model, run.optimizer, rollout, adv, ret,
                      dataclasses.replace(cfg.ppo, update_epochs=6), run.generator)
    assert full.epochs == 6 and full.approx_kl > 1e-6
    run.model.load_state_dict(start, strict=False)
    stopped = ppo_update(run.model, run.optimizer, rollout, adv, ret,
                         dataclasses.replace(cfg.ppo, update_epochs=6, target_kl=1e-9),
                         run.generator)
    assert stopped.epochs == 1  # the first epoch's KL already exceeds a tiny target
    with pytest.raises(ConfigError, match=r"--ppo\.target-kl must be a finite number"):
        dataclasses.replace(cfg.ppo, target_kl=-1.0)


@pytest.mark.parametrize("method,modes,prior", [("ours", 1, False), ("no-mem", 1, False),
                                               ("no-com", 3, False), ("ours", 1, True)])
def test_ppo_scores_a_rollout_with_the_model_that_collected_it(method, modes, prior):
    from collavn.training.map_training import map_parameters
    from collavn.training.trainer import learn

    # 4 envs × 2 agents: the BLAS kernels round a batch of fewer than 8 rows (one step
    # of 2 × 2 agents) differently from a larger one, and the update replays all steps
    # as one batch; from 8 rows on, the results do not depend on the batch size
    _, run, rollout = _fixed_batch(method, num_envs=4, action_modes=modes, explore_prior=prior)
    assert ("explore_action" in rollout.obs) == prior  # stored: the replay adds it again
    assert run.maps.owed > 0  # map updates are owed, not yet taken
    with torch.no_grad():
        out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                         rollout.episode_start, rollout.raw_actions)
    assert torch.equal(out.log_prob, rollout.log_probs)  # first epoch: ratio exactly 1
    # the value: to rounding (≤ 1.1e-7 measured on an AVX-512 CPU, where the kernels of
    # the critic's 1-column head round by batch size; 0 on AVX2 machines)
    torch.testing.assert_close(out.value, rollout.values, rtol=0, atol=1e-6)
    before = [p.detach().clone() for p in map_parameters(run.model)]
    learn(run, rollout)
    assert run.maps.owed == 0 and np.isfinite(run.maps.last_loss)
    assert any(not torch.equal(a, p) for a, p in zip(before, map_parameters(run.model),
                                                    strict=True))


def test_training_logs_communication_rates():
    _, run, _ = _fixed_batch("ours")
    _, stats = collect_rollout(run)
    assert 0.0 <= stats["comm/received_rate"] <= stats["comm/when_rate"] <= 1.0
    assert stats["comm/bytes_per_agent_step"] > 0
    # where the scores sit against η, how much the cores read ω, ψ's bias
    for kind in ("own", "teammate"):
        assert 0.0 < stats[f"comm/{kind}_score"] < 1.0
        assert 0.0 < stats[f"comm/{kind}_score_std"] < 0.5
    assert stats["comm/psi_bias"] == float(run.model.towers[0].comm.psi_bias.detach())
    assert 0.1 < stats["comm/actor_message_weight"] < 10  # fresh weights: comparable
    with torch.no_grad():
        run.model.towers[0].critic_core.weight_ih[:, message_columns(
            run.model.towers[0], "critic_core")] = 0.0
    assert message_weight(run.model)["comm/critic_message_weight"] == 0.0
    _, run, _ = _fixed_batch("no-com")
    _, stats = collect_rollout(run)
    assert (stats["comm/received_rate"], stats["comm/when_rate"],
            stats["comm/bytes_per_agent_step"]) == (0.0, 0.0, 0.0)
    assert not any(k.endswith(("_score", "message_weight", "psi_bias")) for k in stats)


def test_score_tally_separates_own_and_teammate_scores_of_active_agents():
    scores = torch.tensor([[[0.9, 0.2, 0.7], [0.4, 0.6, 0.1], [0.3, 0.3, 0.3]]])
    tally = ScoreTally()
    tally.add(scores, torch.tensor([[True, True, False]]))  # the third agent is done
    rates = tally.rates()
    assert rates["own_score"] == pytest.approx(0.75)
    assert rates["own_score_std"] == pytest.approx(0.15)
    assert rates["teammate_score"] == pytest.approx(0.3)
    assert rates["teammate_score_std"] == pytest.approx(0.1)
    alone = ScoreTally()
    alone.add(scores, torch.tensor([[True, False, False]]))
    assert set(alone.rates()) == {"own_score", "own_score_std"}


def test_action_tally_averages_the_raw_actions_of_active_agents():
    raw = torch.tensor([[[0.5, -1.5], [1.2, 0.5], [9.0, 9.0]]])
    tally = ActionTally()
    tally.add(raw, torch.tensor([[True, True, False]]))  # the third agent is done
    tally.add(torch.tensor([[[0.1, -0.3], [0.0, 0.0], [9.0, 9.0]]]),
              torch.tensor([[True, False, False]]))
    rates = tally.rates()
    assert rates["action/speed"] == pytest.approx((0.5 + 1.2 + 0.1) / 3)
    assert rates["action/turn"] == pytest.approx((-1.5 + 0.5 - 0.3) / 3)
    assert rates["action/abs_turn"] == pytest.approx((1.5 + 0.5 + 0.3) / 3)
    assert rates["action/beyond_bounds"] == pytest.approx(2 / 6)  # −1.5 and 1.2
    assert ActionTally().rates() == {}


def test_training_logs_the_actions_it_took():
    _, run, _ = _fixed_batch("no-com")
    taken = []
    act = run.model.act

    def recorded(obs, state, start, deterministic=False):
        out = act(obs, state, start, deterministic=deterministic)
        taken.append(out.raw_action[obs["active"].bool()])
        return out

    run.model.act = recorded  # type: ignore[method-assign]
    _, stats = collect_rollout(run)
    a = torch.cat(taken).double()
    assert bool((a.abs() > 1).any())  # some samples past the clip: raw, not clipped, counted
    assert stats["action/speed"] == pytest.approx(float(a[:, 0].mean()))
    assert stats["action/turn"] == pytest.approx(float(a[:, 1].mean()))
    assert stats["action/abs_turn"] == pytest.approx(float(a[:, 1].abs().mean()))
    assert stats["action/beyond_bounds"] == pytest.approx(float((a.abs() > 1).double().mean()))


def test_comm_lr_scale_sets_the_messages_apart_and_zero_freezes_them():
    from collavn.training.ppo import comm_parameters

    cfg, run, rollout = _fixed_batch("ours")
    assert len(run.optimizer.param_groups) == 1  # the default: one learning rate
    cfg = dataclasses.replace(cfg, ppo=dataclasses.replace(cfg.ppo, comm_lr_scale=0.0))
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    lrs = [g["lr"] for g in run.optimizer.param_groups]
    assert lrs == [cfg.ppo.lr, 0.0]
    comm = {id(p) for p in comm_parameters(run.model)}
    assert {id(p) for p in run.optimizer.param_groups[1]["params"]} == comm
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    before = {n: p.detach().clone() for n, p in run.model.named_parameters()}
    stats = ppo_update(run.model, run.optimizer, rollout, adv, ret, cfg.ppo, run.generator)
    assert 0.0 < stats.comm_grad_norm < stats.grad_norm  # they were pulled on, not moved
    moved = {n for n, p in run.model.named_parameters() if not torch.equal(p, before[n])}
    assert moved and not any(".comm." in n for n in moved)
    assert any(".actor_core." in n for n in moved)
    with pytest.raises(ConfigError, match=r"--ppo\.comm-lr-scale must be a finite number"):
        dataclasses.replace(cfg.ppo, comm_lr_scale=-0.5)
    _, run, rollout = _fixed_batch("no-com")
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    stats = ppo_update(run.model, run.optimizer, rollout, adv, ret, cfg.ppo, run.generator)
    assert stats.comm_grad_norm == 0.0 < stats.grad_norm


def test_critic_warmup_moves_only_the_critic_and_lowers_the_value_loss(capsys):
    cfg, run, rollout = _fixed_batch("no-com")
    adv, ret = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                           rollout.truncated, rollout.last_value, 0.99, 0.95)
    ppo = dataclasses.replace(cfg.ppo, update_epochs=10, num_minibatches=1)
    for group in run.optimizer.param_groups:
        group["lr"] = 1e-3
    critic = {id(p) for p in critic_parameters(run.model)}
    before = {n: p.detach().clone() for n, p in run.model.named_parameters()}
    _, first = ppo_loss(run.model, rollout, adv, ret, ppo)
    ppo_update(run.model, run.optimizer, rollout, adv, ret, ppo, run.generator,
               critic_only=True)
    _, last = ppo_loss(run.model, rollout, adv, ret, ppo)
    assert last["value_loss"] < first["value_loss"]
    for name, p in run.model.named_parameters():
        if id(p) not in critic:
            assert torch.equal(p.detach(), before[name]), f"{name} moved during warm-up"
    assert any(not torch.equal(p.detach(), before[n]) for n, p in
               run.model.named_parameters() if id(p) in critic)
    # the switch in the trainer: warm-up for the first `critic_warmup` updates only
    run.cfg = dataclasses.replace(run.cfg, ppo=dataclasses.replace(run.cfg.ppo,
                                                                    critic_warmup=1))
    from collavn.training.trainer import learn
    assert learn(run, rollout)["loss/critic_warmup"] == 1.0
    run.iteration = 1
    assert learn(run, rollout)["loss/critic_warmup"] == 0.0
    message = "--ppo.critic-warmup must be an integer ≥ 0, got -1"
    with pytest.raises(CollavnError, match=message):
        dataclasses.replace(run.cfg, ppo=dataclasses.replace(run.cfg.ppo, critic_warmup=-1))
    with pytest.raises(CollavnError, match=message):  # the dispatcher prints it in one line
        parse(["--method", "no-com", "--ppo.critic-warmup", "-1", "--out", "x"])


@pytest.mark.parametrize("modes", [1, 2])
def test_imitation_likelihood_falls_on_a_fixed_batch_and_its_std_is_learned(modes):
    cfg, run, rollout = _fixed_batch("il", action_modes=modes)
    assert rollout.active.any()
    log_std = run.model.towers[0].log_std
    std_before = log_std.detach().clone()
    before = float(imitation_loss(run.model, rollout).detach())
    # the loss is the Gaussian negative log-likelihood of the oracle's actions
    with torch.no_grad():
        out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                         rollout.episode_start, rollout.raw_actions,
                                         rollout.percepts)
        mask = rollout.active
        assert before == pytest.approx(float(-out.log_prob[mask].mean()), rel=1e-5)
    il = dataclasses.replace(cfg.imitation, epochs=15, num_minibatches=1, lr=1e-3)
    for group in run.optimizer.param_groups:
        group["lr"] = 1e-3
    imitation_update(run.model, run.optimizer, [rollout], il, run.generator, 1.0)
    after = float(imitation_loss(run.model, rollout).detach())
    assert after < before - 0.3
    assert log_std.requires_grad and any(id(log_std) == id(p) for g in
                                         run.optimizer.param_groups for p in g["params"])
    assert (log_std.detach() - std_before).abs().min() > 1e-3  # σ follows the residual


def test_belief_labels_on_hand_picked_poses():
    from collavn.models.belief import belief_labels
    # facing +x at the origin: a goal straight ahead, to the left (+y, counter-clockwise),
    # behind, to the right; then facing +y, the goal at +x is to the right
    pose = np.array([[0.0, 0.0, 0.0]] * 4 + [[1.0, 1.0, np.pi / 2]])
    goal = np.array([[2.0, 0.0], [0.0, 3.0], [-1.0, 0.0], [0.0, -0.5], [2.0, 1.0]])
    labels = belief_labels(pose, goal, 16)
    assert labels[:, 0].tolist() == [0, 4, 8, 12, 12]
    assert labels[:, 1] == pytest.approx(np.log1p([2.0, 3.0, 1.0, 0.5, 1.0]))
    # a sector is centred on its direction: ±11.25° either side of straight ahead is 0
    edge = belief_labels(np.zeros((2, 3)), np.array([[1.0, np.tan(0.19)],
                                                     [1.0, -np.tan(0.19)]]), 16)
    assert edge[:, 0].tolist() == [0, 0]
    assert belief_labels(np.zeros((1, 3)), np.array([[1.0, np.tan(0.21)]]), 16)[0, 0] == 1
    from collavn.models.config import ModelConfig
    for bad in (-1, 1):
        with pytest.raises(ValueError, match=f"goal_belief must be 0 .* got {bad}"):
            ModelConfig(goal_belief=bad)


def test_goal_belief_head_learns_in_il_and_nothing_else_changes_without_it():
    from collavn.models.belief import belief_labels
    cfg, run, rollout = _fixed_batch("il", goal_belief=8)
    assert rollout.belief_labels is not None and rollout.active.any()
    # the labels are the privileged pose and goal of the step the action was taken in
    run2 = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run2)
    first = belief_labels(run2.obs["world_pose"], run2.obs["goal_position"], 8)
    assert torch.equal(rollout.belief_labels[0], torch.as_tensor(first))
    head = run.model.towers[0].goal_belief
    assert head is not None and head.out_features == 9
    stats: dict[str, list[float]] = {}
    before = float(imitation_loss(run.model, rollout, 1.0, stats).detach())
    assert before == pytest.approx(stats["imitation"][0] + stats["belief_sector"][0]
                                   + stats["belief_distance"][0], rel=1e-5)
    weight = head.weight.detach().clone()
    il = dataclasses.replace(cfg.imitation, epochs=15, num_minibatches=1)
    for group in run.optimizer.param_groups:
        group["lr"] = 1e-3
    losses = imitation_update(run.model, run.optimizer, [rollout], il, run.generator, 1.0)
    assert set(losses) == {"imitation", "belief_sector", "belief_distance",
                           "belief_accuracy"}
    after: dict[str, list[float]] = {}
    imitation_loss(run.model, rollout, 1.0, after)
    assert after["belief_sector"][0] < stats["belief_sector"][0] - 0.2
    assert after["belief_distance"][0] < stats["belief_distance"][0]
    assert not torch.equal(head.weight, weight)
    # weight 0: the plain likelihood; without the head: no labels are stored
    assert float(imitation_loss(run.model, rollout, 0.0).detach()) == pytest.approx(
        after["imitation"][0], rel=1e-5)
    _, plain_run, plain = _fixed_batch("il")
    assert plain.belief_labels is None and plain_run.model.towers[0].goal_belief is None
    assert set(imitation_update(plain_run.model, plain_run.optimizer, [plain], il,
                                plain_run.generator, 1.0)) == {"imitation"}


def test_homing_weight_weighs_the_seekers_homing_steps():
    from collavn.training.config import ImitationConfig
    cfg = tiny_config(method="il", rollout_steps=24).with_run(num_envs=2)
    assert cfg.imitation.expert == "seeker"
    cfg = dataclasses.replace(cfg, imitation=dataclasses.replace(cfg.imitation,
                                                                 homing_weight=3.0))
    torch.set_num_threads(1)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    sync_point(run)
    rollout, stats = collect_rollout(run)
    assert rollout.weights is not None
    active = rollout.active
    home = (rollout.weights == 3.0) & active
    # easy goals: the seeker homes on some active steps and searches on others, and the
    # logged share is the share of active steps with weight 3
    assert home.any() and ((rollout.weights == 1.0) & active).any()
    assert set(rollout.weights.unique().tolist()) <= {1.0, 3.0}
    assert stats["imitation/homing"] == pytest.approx(float(home.sum() / active.sum()))
    # the homing latch: once an agent's episode homes, it homes until the episode ends
    for e in range(2):
        for n in range(2):
            steps = home[:, e, n].tolist()
            starts = rollout.episode_start[:, e, n].tolist()
            for t in range(1, len(steps)):
                if steps[t - 1] and not starts[t] and active[t, e, n]:
                    assert steps[t], f"env {e} agent {n} stopped homing at step {t}"
    # the loss is the weighted mean of the per-step negative log-likelihoods
    with torch.no_grad():
        out = run.model.evaluate_actions(rollout.obs, rollout.initial_state,
                                         rollout.episode_start, rollout.raw_actions,
                                         rollout.percepts)
        nll = -out.log_prob[active]
        w = rollout.weights[active]
        weighted = float(imitation_loss(run.model, rollout))
        assert weighted == pytest.approx(float((nll * w).sum() / w.sum()), rel=1e-5)
        plain = dataclasses.replace(rollout, weights=None)
        assert float(imitation_loss(run.model, plain)) == pytest.approx(
            float(nll.mean()), rel=1e-5)
    # weight 1 (the default) stores no weights; only the seeker has homing steps
    _, _, unweighted = _fixed_batch("il")
    assert unweighted.weights is None
    with pytest.raises(CollavnError, match=r"--imitation.homing-weight needs "
                                           r"--imitation.expert seeker"):
        ImitationConfig(expert="oracle", homing_weight=2.0)
    with pytest.raises(CollavnError, match=r"--imitation.homing-weight must be a finite "
                                           r"number > 0, got 0"):
        ImitationConfig(expert="seeker", homing_weight=0.0)


def test_map_fifo_keeps_the_newest_samples():
    from collavn.training.map_training import MapFIFO

    fifo = MapFIFO(capacity=3)
    for start in (0, 2):
        fifo.push({"x": np.arange(start, start + 2)[:, None]})
    assert fifo.size == 3
    assert sorted(fifo.data["x"][:, 0].tolist()) == [1, 2, 3]
    batch = fifo.sample(50, np.random.default_rng(0))["x"][:, 0]
    assert set(batch.tolist()) == {1, 2, 3}
    fifo.clear()
    assert fifo.size == 0


def test_map_fifo_push_in_batches_equals_push_one_by_one():
    from collavn.training.map_training import MapFIFO

    rng = np.random.default_rng(3)
    batched, single = MapFIFO(capacity=5), MapFIFO(capacity=5)
    history: list[np.ndarray] = []
    for count in (2, 4, 0, 7, 1, 5, 3):  # wraps around, and once more than fit
        x = rng.normal(size=(count, 2))
        history += list(x)
        batched.push({"x": x, "y": x.sum(1).astype(np.float32)})
        for row in x:
            single.push({"x": row[None], "y": row.sum(keepdims=True).astype(np.float32)})
        assert (batched.size, batched.cursor) == (single.size, single.cursor)
        np.testing.assert_array_equal(batched.data["x"], single.data["x"])
        np.testing.assert_array_equal(batched.data["y"], single.data["y"])
        # it holds exactly the newest samples, the newest just before the cursor
        newest = history[-batched.size:]
        held = batched.data["x"][:batched.size]
        assert sorted(map(tuple, held)) == sorted(map(tuple, newest))
        np.testing.assert_array_equal(batched.data["x"][batched.cursor - 1], history[-1])
    assert batched.size == 5


def test_dagger_mixing_and_beta_schedule():
    from collavn.training.config import ImitationConfig
    from collavn.training.imitation import expert_probability, mix_actions

    assert expert_probability(ImitationConfig(dagger=False), 50) == 1.0
    cfg = ImitationConfig(dagger=True, beta_decay=0.5, beta_min=0.2)
    assert [expert_probability(cfg, i) for i in range(4)] == [1.0, 0.5, 0.25, 0.2]
    learner, expert = np.zeros((1000, 2, 2)), np.ones((1000, 2, 2))
    mixed = mix_actions(learner, expert, 0.3, np.random.default_rng(0))
    per_env = mixed[:, 0, 0]
    assert np.all(mixed == per_env[:, None, None])  # one choice per env and step
    assert 0.25 < per_env.mean() < 0.35


def test_envs_visit_every_training_scene_when_there_are_more_scenes_than_envs():
    scenes = list("abcde")
    windows = [scene_window(scenes, 2, k) for k in range(5)]  # type: ignore[arg-type]
    assert windows[:3] == [["a", "b"], ["c", "d"], ["e", "a"]]
    assert {s for w in windows for s in w} == set(scenes)
    assert scene_window(scenes, 8, 3) == scenes  # all fit: no rotation


def test_sync_points_move_the_envs_to_the_next_scenes():
    cfg = tiny_config("no-com").with_run(num_envs=1, checkpoint_interval=1,
                                         scenes=("procedural:0", "procedural:1"))
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    seen = []
    for k in range(3):
        run.iteration = k
        sync_point(run)
        seen.append(run.env.scenes[0].name)
    assert seen == ["procedural:0", "procedural:1", "procedural:0"]


def test_train_scenes_picks_the_first_seeds_of_the_train_range():
    cfg = tiny_config("no-com").with_run(num_envs=1, scenes=(), train_scenes=3)
    run = build_run(cfg, DistInfo(), torch.device("cpu"))
    assert [s.name for s in run.scenes] == ["procedural:0", "procedural:1", "procedural:2"]
    # explicit --scenes win over the count
    run = build_run(tiny_config("no-com").with_run(train_scenes=3), DistInfo(),
                    torch.device("cpu"))
    assert [s.name for s in run.scenes] == ["procedural:0"]
    with pytest.raises(ConfigError, match=r"--train-scenes must be at most 1000"):
        RunConfig(train_scenes=1001)


def test_imitation_lr_decay_is_linear_in_agent_steps_and_survives_a_resume():
    from collavn.training.trainer import learn

    cfg, run, rollout = _fixed_batch("il")
    base = cfg.imitation.lr
    total = 4 * run.steps_per_update
    run.cfg = dataclasses.replace(cfg.with_run(total_steps=total), imitation=dataclasses.replace(
        cfg.imitation, lr_decay=True))
    run.agent_steps = run.steps_per_update
    assert learn(run, rollout)["opt/learning_rate"] == pytest.approx(0.75 * base)
    # a resumed optimizer keeps the first rate and continues the schedule from it
    state = run.optimizer.state_dict()
    run.optimizer = torch.optim.Adam([p for g in run.optimizer.param_groups
                                      for p in g["params"]], lr=123.0)
    run.optimizer.load_state_dict(state)
    run.agent_steps = 3 * run.steps_per_update
    assert learn(run, rollout)["opt/learning_rate"] == pytest.approx(0.25 * base)
    # at total_steps the rate is 0: the weights no longer move
    run.agent_steps = total
    before = {n: p.detach().clone() for n, p in run.model.named_parameters()}
    assert learn(run, rollout)["opt/learning_rate"] == 0.0
    for name, p in run.model.named_parameters():
        assert torch.equal(p.detach(), before[name]), name
    # without the flag the rate stays put
    fresh = _fixed_batch("il")[1]
    fresh.agent_steps = 3 * fresh.steps_per_update
    assert learn(fresh, rollout)["opt/learning_rate"] == base


def test_adam_is_fused_on_cpu_and_steps_like_the_unfused_one():
    from collavn.models.optim import adam

    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Linear(6, 5), torch.nn.Tanh(), torch.nn.Linear(5, 2))
    twin, start = copy.deepcopy(net), copy.deepcopy(net)
    fused = adam([{"params": net.parameters()}], lr=0.01, eps=1e-5)
    plain = torch.optim.Adam(twin.parameters(), lr=0.01, eps=1e-5)
    assert fused.defaults["fused"] is True and not plain.defaults["fused"]
    x = torch.randn(16, 6)
    for _ in range(5):
        for model, opt in ((net, fused), (twin, plain)):
            opt.zero_grad()
            model(x).pow(2).mean().backward()
            opt.step()
    for a, b in zip(net.parameters(), twin.parameters(), strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-6)
    assert not torch.allclose(net[0].weight, start[0].weight)  # it did train
    plain.load_state_dict(fused.state_dict())  # the same state-dict form both ways
