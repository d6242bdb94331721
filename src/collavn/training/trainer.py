"""The training loop: collect a rollout → bootstrap → GAE → PPO epochs → log → checkpoint.

:func:`train` reads in the algorithm's order; each step is a named function below.
Method ``il`` replaces "GAE + PPO" by a supervised step on the expert's actions
(:mod:`collavn.training.imitation`); the map module learns alongside from its FIFO
(:mod:`collavn.training.map_training`) between policy updates, from the samples of the
rollouts.

Reproducibility: every ``checkpoint_interval`` updates is a *sync point* — all seeds
are re-derived from ``(seed, rank, update)``, every env starts a new episode, the
recurrent state and the map FIFO are cleared. A checkpoint is written at sync points,
so a run resumed from one continues exactly like the uninterrupted run. That is why a
SIGINT or SIGTERM (:mod:`collavn.training.interrupt`) stops at the next sync point, not
mid-interval; a run stopped by its time budget stops where it is, and a resume from
that checkpoint starts a sync point there (statistically the same run, not bit-equal).

Run directory: :func:`collavn.files.prepare_output_dir` refuses a non-empty ``out``
unless ``resume`` (which then requires ``out/checkpoint.pt``) or ``overwrite`` (the old
directory is moved aside); ``resume_from`` continues another run's checkpoint in a new
``out``.
"""

from __future__ import annotations

import copy
import json
import math
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn

from collavn.configs import to_dict
from collavn.envs.config import EnvConfig
from collavn.envs.vector import VectorEnv
from collavn.errors import CheckpointError
from collavn.files import prepare_output_dir
from collavn.models.belief import belief_labels
from collavn.models.optim import adam
from collavn.models.policy import ActorCritic, AgentTower
from collavn.models.state import AgentState
from collavn.perception.encoder import EncoderFile, install_encoder, load_encoder
from collavn.policies.adapter import episode_start, obs_to_torch, policy_keys
from collavn.policies.base import CommStats
from collavn.policies.checkpoint import (
    checkpoint_model_config,
    load_checkpoint,
    save_checkpoint,
    tally,
)
from collavn.policies.oracle import track_sighting
from collavn.scenes import Scene, load_scene
from collavn.scenes.splits import scene_specs
from collavn.threads import apply_threads
from collavn.training import distributed
from collavn.training.checkpoint import SNAPSHOTS, check_config, differences, snapshot_name
from collavn.training.config import TrainConfig
from collavn.training.imitation import (
    Expert,
    expert_probability,
    imitation_update,
    mix_actions,
)
from collavn.training.interrupt import StopRequest
from collavn.training.map_training import MapTrainer, policy_parameters
from collavn.training.ppo import comm_parameters, explained_variance, ppo_update
from collavn.training.rollout import Rollout, compute_gae

CHECKPOINT = "checkpoint.pt"


@dataclass
class Run:
    """Everything a training process holds between updates."""

    cfg: TrainConfig
    info: distributed.DistInfo
    device: torch.device
    env: VectorEnv
    model: ActorCritic
    optimizer: torch.optim.Optimizer
    maps: MapTrainer
    expert: Expert | None
    obs: dict[str, np.ndarray] = field(default_factory=dict)
    state: AgentState | None = None
    iteration: int = 0
    agent_steps: int = 0
    generator: torch.Generator = field(default_factory=torch.Generator)
    rng: np.random.Generator = field(default_factory=np.random.default_rng)
    returns: np.ndarray = field(default_factory=lambda: np.zeros(0))
    window: dict[str, deque[float]] = field(default_factory=lambda: {
        k: deque(maxlen=200) for k in ("success", "return", "length")})
    demos: deque[Rollout] = field(default_factory=deque)
    scenes: list[Scene] = field(default_factory=list)
    anchor: ActorCritic | None = None
    """A frozen copy of the ``--init-from`` policy (``--ppo.bc-target init``)."""
    anchor_state: AgentState | None = None
    """The anchor's recurrent state after the last rollout it replayed."""
    sighted: np.ndarray | None = None
    """``(E, N)`` the goal has been in sight this episode (``--ppo.bc-steps sighted``)."""
    since_collision: np.ndarray | None = None
    """``(E, N)`` steps since the agent last collided this episode, at most the window
    (``--ppo.bc-steps blocked``)."""
    started: float = field(default_factory=time.perf_counter)

    @property
    def steps_per_update(self) -> int:
        """Agent-steps per update over all processes."""
        c = self.cfg
        return c.ppo.rollout_steps * c.run.num_envs * c.env.num_agents * self.info.world_size


def env_config(cfg: TrainConfig) -> EnvConfig:
    """``cfg.env`` plus what the run needs: depth, gt maps for the map, expert info.

    ``depth``, ``free_space``, ``explore_action``, ``gt_map``, ``gt_map_size`` and
    ``privileged`` are set here, from the model and the method, whatever ``cfg.env`` says.
    """
    m = cfg.model.map
    seeker = has_expert(cfg) and cfg.imitation.expert == "seeker"
    sighting = bc_on_sighted_steps(cfg)
    return replace(cfg.env, depth=cfg.model.reads_depth or seeker,
                   free_space=cfg.model.free_space_input,
                   explore_action=cfg.model.explore_prior, gt_map=cfg.mapping.enabled,
                   gt_map_size=round(m.local_size * m.resolution / 0.1),
                   privileged=has_expert(cfg) or sighting)


def has_expert(cfg: TrainConfig) -> bool:
    """The run consults an expert: ``il``, or PPO with a behaviour-cloning term on it."""
    return cfg.method_spec.imitation or (cfg.ppo_clones and cfg.ppo.bc_target == "expert")


def bc_on_sighted_steps(cfg: TrainConfig) -> bool:
    """PPO's behaviour-cloning term weighs only steps after the goal was in sight."""
    return cfg.ppo_clones and cfg.ppo.bc_steps == "sighted"


def bc_on_blocked_steps(cfg: TrainConfig) -> bool:
    """PPO's behaviour-cloning term weighs only steps shortly after a collision."""
    return cfg.ppo_clones and cfg.ppo.bc_steps == "blocked"


def steps_since_collision(since: np.ndarray, collided: np.ndarray, window: int) -> np.ndarray:
    """Steps since each agent's last collision after one more step, capped at ``window``.

    ``since`` counts before the step, ``collided`` ``(E, N)`` is the step's
    ``info["collided"]``; ``window`` means "none within the window" (and a new episode's
    start, which :func:`collect_rollout` sets). Returns a new array.
    """
    return np.where(collided, 0, np.minimum(since + 1, window))


def has_anchor(cfg: TrainConfig) -> bool:
    """PPO's behaviour-cloning term imitates the ``--init-from`` policy's mean action."""
    return cfg.ppo_clones and cfg.ppo.bc_target == "init"


def set_train_mode(model: nn.Module) -> None:
    """``train()`` with batch-norm statistics frozen.

    Frozen statistics keep log-probabilities at collection and at update equal (PPO's
    ratio is 1 before the first step) whatever the batch composition.
    """
    model.train()
    for m in model.modules():
        if isinstance(m, nn.modules.batchnorm._BatchNorm):
            m.eval()


def resolve_encoder(cfg: TrainConfig) -> tuple[TrainConfig, EncoderFile | None]:
    """Load ``--encoder`` and record its checksum in the config (refuse a changed file)."""
    if not cfg.run.encoder:
        return cfg, None
    encoder = load_encoder(cfg.run.encoder)
    if cfg.run.encoder_sha256 and cfg.run.encoder_sha256 != encoder.sha256:
        raise CheckpointError(f"encoder {cfg.run.encoder} has checksum {encoder.sha256[:12]}…, "
                              f"not the {cfg.run.encoder_sha256[:12]}… this run was made with")
    return cfg.with_run(encoder_sha256=encoder.sha256), encoder


def build_run(cfg: TrainConfig, info: distributed.DistInfo, device: torch.device) -> Run:
    """Threads, scenes, envs, model, optimizers.

    The model has the same initial weights on every rank; a pretrained encoder is
    installed and frozen.
    """
    apply_threads(cfg.run.torch_threads)
    cfg, encoder = resolve_encoder(cfg)
    specs = list(cfg.run.scenes) or scene_specs("train", (cfg.run.train_scenes, 0, 0))
    scenes = [load_scene(cfg.run.load.spec(s)) for s in distributed.shard(specs, info)]
    env = VectorEnv(scene_window(scenes, cfg.run.num_envs, 0), cfg.run.num_envs,
                    env_config(cfg), seed=info.seed(cfg.run.seed))
    torch.manual_seed(cfg.run.seed)
    model = ActorCritic(cfg.model, device=device)
    anchor = None
    if cfg.run.init_from:
        initialise_from(model, cfg, cfg.run.init_from)
        if has_anchor(cfg):  # before anything changes the model (σ, a resume)
            anchor = copy.deepcopy(model).requires_grad_(False).eval()
    if cfg.ppo.start_std > 0 and not cfg.method_spec.imitation:
        with torch.no_grad():
            for tower in model.towers:
                assert isinstance(tower, AgentTower)
                tower.log_std.fill_(math.log(cfg.ppo.start_std))
                if cfg.ppo.end_std > 0:  # set by anneal_std, not trained
                    tower.log_std.requires_grad_(False)
    if encoder is not None:
        install_encoder(model, encoder, cfg.env.camera_height)
        if anchor is not None:
            install_encoder(anchor, encoder, cfg.env.camera_height)
    distributed.broadcast_parameters(model)
    set_train_mode(model)
    optimizer = adam(parameter_groups(model, cfg), lr=cfg.learning_rate, eps=1e-5)
    maps = MapTrainer(model, cfg.mapping, cfg.model.map.use_depth, info.seed(cfg.run.seed),
                      distributed.average_gradients if info.enabled else None)
    expert = (Expert(cfg.imitation, env.scenes, env.num_envs, env.num_agents, cfg.run.seed)
              if has_expert(cfg) else None)
    return Run(cfg, info, device, env, model, optimizer, maps, expert, scenes=scenes,
               anchor=anchor)


def parameter_groups(model: ActorCritic, cfg: TrainConfig) -> list[dict[str, Any]]:
    """The policy optimizer's parameter groups.

    One group, or the communication parameters apart at ``lr × ppo.comm_lr_scale`` when
    that is not 1 and the model has any (``no-com`` and ``il`` have none).
    """
    params = policy_parameters(model)
    comm = {id(p) for p in comm_parameters(model)}
    if cfg.ppo.comm_lr_scale == 1.0 or not comm:
        return [{"params": params}]
    return [{"params": [p for p in params if id(p) not in comm]},
            {"params": [p for p in params if id(p) in comm],
             "lr": cfg.learning_rate * cfg.ppo.comm_lr_scale}]


def scene_window(scenes: list[Scene], num_envs: int, k: int) -> list[Scene]:
    """The scenes the envs use between the ``k``-th and ``k+1``-th sync point.

    All of them if they fit in ``num_envs`` envs, else ``num_envs`` consecutive ones
    (cyclically) from ``k · num_envs`` on, so every training scene gets visited.
    """
    if len(scenes) <= num_envs:
        return scenes
    return [scenes[(k * num_envs + i) % len(scenes)] for i in range(num_envs)]


def initialise_from(model: ActorCritic, cfg: TrainConfig, path: str) -> None:
    """Load a checkpoint's model weights into ``model``; refuse another model config.

    One difference is allowed: a checkpoint without communication (``il``, ``no-com``)
    may start a run with it (``ours``, ``no-mem``). The message enters the GRU cores
    through new input columns that start at zero, so the run's first policy is the
    checkpoint's; the communication weights start fresh and learn from there.
    """
    payload = load_checkpoint(path)  # only its model matters (not its method or expert)
    saved = to_dict(checkpoint_model_config(payload, path))
    diffs = differences(saved, cfg.to_dict()["model"], "model.")
    adds_messages = (saved["comm"]["variant"] == "none" != cfg.model.comm.variant
                     and all(d.startswith("model.comm.") for d in diffs))
    if diffs and not adds_messages:
        raise CheckpointError(f"--init-from {path}: its model config differs from this "
                              f"run's ({'; '.join(diffs[:6])}); use the same preset")
    state = payload["model"]
    if adds_messages:
        state = with_message_inputs(state, model)
    missing, unexpected = model.load_state_dict(state, strict=not adds_messages)
    if unexpected or any(".comm." not in k for k in missing):
        raise CheckpointError(f"--init-from {path}: weights do not fit this model "
                              f"(missing {missing[:3]}, unexpected {unexpected[:3]})")


def with_message_inputs(state: dict[str, torch.Tensor], model: ActorCritic
                        ) -> dict[str, torch.Tensor]:
    """A silent model's weights with zero-weight message inputs for ``model``'s cores.

    The actor core reads ``[o, s, ω, g]`` and the critic core ``[o, ω, (s, g)]``
    (:meth:`~collavn.models.policy.AgentTower.core_inputs`): ω's columns are inserted
    as zeros, every other column keeps its weight.
    """
    out = dict(state)
    for i, tower in enumerate(model.towers):
        assert isinstance(tower, AgentTower)
        for core in ("actor_core", "critic_core"):
            key = f"towers.{i}.{core}.weight_ih"
            old, cols = state[key], message_columns(tower, core)
            out[key] = torch.cat([old[:, :cols.start],
                                  old.new_zeros(old.shape[0], cols.stop - cols.start),
                                  old[:, cols.start:]], dim=1)
    return out


def message_columns(tower: AgentTower, core: str) -> slice:
    """The input columns of ``tower``'s ``actor_core`` or ``critic_core`` that read ω."""
    assert tower.comm is not None
    at = tower.embed_size + (tower.map_vector_size if core == "actor_core" else 0)
    return slice(at, at + tower.comm.output_size)


def message_weight(model: ActorCritic) -> dict[str, float]:
    """How much the GRU cores read ω, and where ψ's bias stands (towers averaged).

    ``comm/actor_message_weight``: mean norm of the actor core's ω columns over the mean
    norm of its other input columns (0 at ``--init-from`` a silent checkpoint, ~1 when ω
    weighs like any other input); ``comm/critic_message_weight`` the same for the
    critic; ``comm/psi_bias`` the bias b of ψ = σ(μᵀWκ/√d + b), which moves every score.
    """
    out: dict[str, list[float]] = {"comm/actor_message_weight": [],
                                   "comm/critic_message_weight": [], "comm/psi_bias": []}
    for tower in model.towers:
        assert isinstance(tower, AgentTower)
        if tower.comm is None:
            continue
        for core in ("actor_core", "critic_core"):
            norms = getattr(tower, core).weight_ih.detach().norm(dim=0)
            cols = torch.zeros_like(norms, dtype=torch.bool)
            cols[message_columns(tower, core)] = True
            ratio = norms[cols].mean() / norms[~cols].mean().clamp(min=1e-12)
            out[f"comm/{core.split('_')[0]}_message_weight"].append(float(ratio))
        out["comm/psi_bias"].append(float(tower.comm.psi_bias.detach()))
    return {k: float(np.mean(v)) for k, v in out.items() if v}


@dataclass
class ScoreTally:
    """The agents' scores over a rollout: s_{n,n} (own memory) and s_{n,m} (teammates).

    The gates open where a score passes η (½ at N = 2), so where these sit against η
    says whether messages flow and how far a gate is from flipping.
    """

    own: list[float] = field(default_factory=list)
    teammate: list[float] = field(default_factory=list)

    def add(self, scores: torch.Tensor, active: torch.Tensor) -> None:
        """One step's ``(E, N, N)`` scores of the ``(E, N)`` active agents."""
        active = active.bool()
        eye = torch.eye(scores.shape[1], dtype=torch.bool, device=scores.device)
        pairs = active.unsqueeze(2) & active.unsqueeze(1)
        self.own += scores[pairs & eye].tolist()
        self.teammate += scores[pairs & ~eye].tolist()

    def rates(self) -> dict[str, float]:
        """Mean and standard deviation of both kinds of score (empty kinds left out)."""
        out: dict[str, float] = {}
        for name, values in (("own", self.own), ("teammate", self.teammate)):
            if values:
                out[f"{name}_score"] = float(np.mean(values))
                out[f"{name}_score_std"] = float(np.std(values))
        return out


@dataclass
class ActionTally:
    """The raw (unclipped) actions the learner took over a rollout's active agent-steps.

    PPO's are samples (the mean plus σ noise), ``il``'s its mean action. A mean that
    drifts shows here before it shows in the success rate: ``action/turn`` (the signed
    mean of a[1]) moving away from 0 is a policy that turns one way whatever it sees
    (docs/learning-log.md, 2026-12-08: an ``ours`` run from ``il`` whose mean turn on val
    drifted to −0.7 through PPO, spinning clockwise), and ``action/beyond_bounds`` is
    the share of action components past ±1, where the env clips them and PPO's ratio no
    longer sees the difference.
    """

    steps: int = 0
    total: np.ndarray = field(default_factory=lambda: np.zeros(2))
    absolute: np.ndarray = field(default_factory=lambda: np.zeros(2))
    beyond: int = 0

    def add(self, raw: torch.Tensor, active: torch.Tensor) -> None:
        """One step's ``(E, N, 2)`` raw actions of the ``(E, N)`` active agents."""
        a = raw[active.bool()].detach().double().cpu().numpy()
        self.steps += a.shape[0]
        self.total += a.sum(0)
        self.absolute += np.abs(a).sum(0)
        self.beyond += int((np.abs(a) > 1.0).sum())

    def rates(self) -> dict[str, float]:
        """The tally's scalars (empty without active steps).

        ``action/speed``, ``action/turn`` (signed means), ``action/abs_turn`` and
        ``action/beyond_bounds``.
        """
        if not self.steps:
            return {}
        mean, absolute = self.total / self.steps, self.absolute / self.steps
        return {"action/speed": float(mean[0]), "action/turn": float(mean[1]),
                "action/abs_turn": float(absolute[1]),
                "action/beyond_bounds": self.beyond / (2 * self.steps)}


def sync_point(run: Run) -> None:
    """Re-derive every seed from (seed, rank, update) and start fresh episodes."""
    seed = run.info.seed(run.cfg.run.seed) + 7919 * run.iteration
    torch.manual_seed(seed)
    run.generator.manual_seed(seed)
    run.rng = np.random.default_rng(seed)
    run.maps.reseed(seed)
    window = scene_window(run.scenes, run.cfg.run.num_envs,
                          run.iteration // run.cfg.run.checkpoint_interval)
    if [s.name for s in window] != [s.name for s in run.env.scenes]:  # next scenes
        run.env = VectorEnv(window, run.cfg.run.num_envs, env_config(run.cfg), seed=seed)
    if run.expert is not None:  # a fresh memory, as after a resume
        run.expert = Expert(run.cfg.imitation, run.env.scenes, run.env.num_envs,
                            run.env.num_agents, seed)
    run.obs, _ = run.env.reset(seed=seed)
    run.state = run.model.initial_state(run.env.num_envs, run.env.num_agents)
    if run.anchor is not None:
        run.anchor_state = run.anchor.initial_state(run.env.num_envs, run.env.num_agents)
    if bc_on_sighted_steps(run.cfg):
        run.sighted = np.zeros((run.env.num_envs, run.env.num_agents), dtype=bool)
    if bc_on_blocked_steps(run.cfg):
        run.since_collision = np.full((run.env.num_envs, run.env.num_agents),
                                      run.cfg.ppo.bc_blocked_window, dtype=np.int64)
    run.returns = np.zeros((run.env.num_envs, run.env.num_agents))
    run.demos = deque(maxlen=run.cfg.imitation.buffer_rollouts)


def collect_rollout(run: Run) -> tuple[Rollout, dict[str, float]]:
    """Step the envs ``rollout_steps`` times with the current policy (or the expert mix).

    Returns:
        The rollout (with ``last_value`` bootstrapped) and collection statistics.
    """
    cfg, model, device = run.cfg, run.model, run.device
    keys = policy_keys(cfg.model)
    assert run.state is not None
    obs_t = obs_to_torch(run.obs, keys, device)
    rollout: Rollout | None = None
    imitating = cfg.method_spec.imitation
    beta = expert_probability(cfg.imitation, run.iteration)
    # the goal-belief head learns in il, from the privileged observations the expert reads
    believing = imitating and bool(model.cfg.goal_belief)
    weighing = imitating and cfg.imitation.homing_weight != 1.0
    sighting = run.sighted is not None  # PPO's BC term weighs the sighted steps only
    blocking = run.since_collision is not None  # … or the steps after a collision
    window = cfg.ppo.bc_blocked_window
    homing: list[int] = []  # per step, active agents the expert homes (seeker only)
    comm, scores, taken = CommStats(), ScoreTally(), ActionTally()
    start = time.perf_counter()
    for t in range(cfg.ppo.rollout_steps):
        start_t = episode_start(run.obs, device)
        # DAgger's learner drives with its mean action, the policy that is evaluated: the
        # expert then labels the states that action reaches (pressed against a wall, …)
        out = model.act(obs_t, run.state, start_t, deterministic=imitating)
        if rollout is None:  # stores only what the update reads (see Rollout)
            rollout = Rollout.allocate(
                cfg.ppo.rollout_steps, {k: obs_t[k] for k in model.replay_keys()},
                run.state, {k: out.percepts[k] for k in model.stored_percepts},
                expert=(run.expert is not None or run.anchor is not None) and not imitating,
                belief=believing,
                weights=weighing or sighting or blocking)
        actions = out.action.cpu().numpy().astype(np.float64)
        stored = out.raw_action
        if run.expert is not None:
            expert_np = run.expert.act(run.obs)
            expert = torch.as_tensor(expert_np, dtype=torch.float32, device=device)
            if imitating:  # DAgger's mix; the expert's action is the target
                actions = mix_actions(actions, expert_np, beta, run.rng)
                stored = expert
                seen = run.expert.homing()
                if seen is not None:
                    home = seen & run.obs["active"]
                    homing.append(int(home.sum()))
                    if rollout.weights is not None:
                        rollout.weights[t] = torch.as_tensor(
                            np.where(home, cfg.imitation.homing_weight, 1.0), device=device)
            else:  # PPO's behaviour-cloning target beside the policy's own action
                assert rollout.expert_actions is not None
                rollout.expert_actions[t] = expert
            run.expert.executed(actions, run.obs["active"])
        if run.sighted is not None:
            run.sighted = track_sighting(run.sighted, run.obs, run.env.scenes,
                                         cfg.imitation.sight)
            assert rollout.weights is not None
            rollout.weights[t] = torch.as_tensor(run.sighted, device=device)
        if run.since_collision is not None:  # a new episode forgets the last one's
            run.since_collision[run.obs["step"] == 0] = window
            assert rollout.weights is not None
            rollout.weights[t] = torch.as_tensor(run.since_collision < window, device=device)
        rollout.insert(t, obs_t, start_t, stored, out.log_prob, out.value, out.percepts)
        if rollout.belief_labels is not None:
            rollout.belief_labels[t] = torch.as_tensor(belief_labels(
                run.obs["world_pose"], run.obs["goal_position"], model.cfg.goal_belief),
                device=device)
        comm.add(tally(out.message, obs_t["active"]))
        taken.add(out.raw_action, obs_t["active"])
        if model.cfg.comm.variant != "none":
            scores.add(out.message.scores, obs_t["active"])
        run.maps.observe(run.obs)
        run.obs, reward, terminated, truncated, info = run.env.step(actions)
        rollout.insert_outcome(t, reward, terminated, truncated)
        if run.since_collision is not None:
            run.since_collision = steps_since_collision(run.since_collision,
                                                        info["collided"], window)
        track_episodes(run, reward, info)
        run.state = out.state
        obs_t = obs_to_torch(run.obs, keys, device)
    assert rollout is not None
    with torch.no_grad():
        rollout.last_value = model(obs_t, run.state, episode_start(run.obs, device)).value
    seconds = time.perf_counter() - start
    return rollout, {**{f"comm/{k}": v for k, v in comm.rates().items()},
                     **{f"comm/{k}": v for k, v in scores.rates().items()},
                     **message_weight(model), **taken.rates(),
                     "perf/collect_seconds": seconds,
                     **({"imitation/beta": beta} if imitating else {}),
                     **({"imitation/homing": sum(homing) / max(float(rollout.active.sum()), 1.0)}
                        if homing else {})}


def track_episodes(run: Run, reward: np.ndarray, info: dict[str, Any]) -> None:
    """Accumulate per-agent returns; remember success, return and length of ended episodes."""
    run.returns += reward
    done = info["episode_done"]
    run.window["return"].extend(run.returns[done].ravel().tolist())
    run.returns[done] = 0.0
    for r in info["episode_records"]:
        run.window["success"].append(float(r.success))
        run.window["length"].append(float(r.steps))


def learn(run: Run, rollout: Rollout) -> dict[str, float]:
    """GAE + PPO epochs (or the imitation step for ``il``); returns losses to log."""
    cfg = run.cfg
    sync = ((lambda: distributed.average_gradients(policy_parameters(run.model)))
            if run.info.enabled else None)
    if cfg.method_spec.imitation:
        run.demos.append(rollout)
        if cfg.imitation.lr_decay:
            scale_learning_rate(run.optimizer, 1.0 - run.agent_steps / cfg.run.total_steps)
        losses = imitation_update(run.model, run.optimizer, list(run.demos), cfg.imitation,
                                  run.generator, cfg.ppo.max_grad_norm, sync)
        run.maps.train_owed()
        return {**{f"loss/{k}": v for k, v in losses.items()},
                "opt/learning_rate": run.optimizer.param_groups[0]["lr"]}
    advantages, returns = compute_gae(rollout.rewards, rollout.values, rollout.terminated,
                                      rollout.truncated, rollout.last_value, cfg.ppo.gamma,
                                      cfg.ppo.gae_lambda)
    warmup = run.iteration < cfg.ppo.critic_warmup
    if run.anchor is not None:
        anchor_targets(run, rollout)
    bc_weight = cfg.ppo.bc_coef * cfg.ppo.bc_decay ** run.iteration
    stats = ppo_update(run.model, run.optimizer, rollout, advantages, returns, cfg.ppo,
                       run.generator, sync, critic_only=warmup, bc_weight=bc_weight)
    run.maps.train_owed()  # between updates: the next rollout is scored as collected
    # the values the rollout was collected with, before this update moved the critic
    explained = explained_variance(rollout.values, returns, rollout.active)
    return {f"loss/{k}": v for k, v in stats.__dict__.items()} | {
        "loss/critic_warmup": float(warmup), "loss/explained_variance": explained,
        "opt/action_std": action_std(run.model)}


def action_std(model: ActorCritic) -> float:
    """The policy's σ, averaged over agents' towers and action dimensions."""
    return float(torch.stack([t.log_std.detach().exp().mean() for t in model.towers
                              if isinstance(t, AgentTower)]).mean())


def annealed_std(cfg: TrainConfig, agent_steps: int) -> float:
    """σ at ``agent_steps`` under ``--ppo.end-std``: log σ linear from start to end."""
    frac = min(max(agent_steps / cfg.run.total_steps, 0.0), 1.0)
    return math.exp((1.0 - frac) * math.log(cfg.ppo.start_std)
                    + frac * math.log(cfg.ppo.end_std))


def anneal_std(run: Run) -> None:
    """Set every tower's σ from the schedule before a rollout (``--ppo.end-std`` > 0)."""
    cfg = run.cfg
    if cfg.ppo.end_std <= 0 or cfg.method_spec.imitation:
        return
    log_std = math.log(annealed_std(cfg, run.agent_steps))
    with torch.no_grad():
        for tower in run.model.towers:
            assert isinstance(tower, AgentTower)
            tower.log_std.fill_(log_std)


def anchor_targets(run: Run, rollout: Rollout) -> None:
    """Fill ``rollout.expert_actions`` with the anchor policy's mean actions.

    The frozen ``--init-from`` copy replays the rollout's stored inputs from its own
    recurrent state, carried from rollout to rollout (and reset with the policy's at
    sync points), so it acts as if it had driven along the states the policy visited.
    """
    assert run.anchor is not None and run.anchor_state is not None
    assert rollout.expert_actions is not None
    actions, run.anchor_state = run.anchor.mean_actions(
        rollout.obs, run.anchor_state, rollout.episode_start, rollout.percepts)
    rollout.expert_actions.copy_(actions)


def scale_learning_rate(optimizer: torch.optim.Optimizer, fraction: float) -> None:
    """Set every group's learning rate to ``fraction`` (clipped to [0, 1]) of its first.

    The first rate is kept in the group (``base_lr``), so a resumed optimizer continues
    the schedule from its checkpoint.
    """
    fraction = min(max(fraction, 0.0), 1.0)
    for group in optimizer.param_groups:
        group["lr"] = group.setdefault("base_lr", group["lr"]) * fraction


def summary(run: Run, collect: dict[str, float], losses: dict[str, float],
            seconds: float) -> dict[str, float]:
    """Scalars of one update, averaged over processes."""
    steps = run.steps_per_update / run.info.world_size
    window = {k: np.asarray(v, dtype=float) for k, v in run.window.items()}
    scalars = {
        "episode/success_rate": float(window["success"].mean()) if len(window["success"])
        else 0.0,
        "episode/return": float(window["return"].mean()) if len(window["return"]) else 0.0,
        "episode/length": float(window["length"].mean()) if len(window["length"]) else 0.0,
        "loss/map": run.maps.last_loss,
        "perf/collect_agent_steps_per_s": steps / max(collect["perf/collect_seconds"], 1e-9),
        "perf/agent_steps_per_s": steps / max(seconds, 1e-9),
        **collect, **losses,
    }
    names = sorted(scalars)
    values = distributed.all_reduce_mean([scalars[k] for k in names], run.device)
    out = dict(zip(names, values, strict=True))
    out["perf/agent_steps_per_s"] *= run.info.world_size
    out["perf/collect_agent_steps_per_s"] *= run.info.world_size
    return out


def checkpoint_payload(run: Run) -> dict[str, Any]:
    """What a checkpoint holds (everything else is re-derived at sync points)."""
    return {"config": run.cfg.to_dict(), "iteration": run.iteration,
            "agent_steps": run.agent_steps, "model": run.model.state_dict(),
            "optimizer": run.optimizer.state_dict(),
            "map_optimizer": run.maps.optimizer.state_dict()}


def next_snapshot(run: Run) -> int:
    """The agent-step count whose passing keeps the next snapshot (0: no snapshots)."""
    every = run.cfg.run.snapshot_every
    return (run.agent_steps // every + 1) * every if every else 0


def save_checkpoints(out: Path, run: Run, mark: int) -> tuple[Path, int]:
    """Write ``OUT/checkpoint.pt``, and a snapshot once the run has passed ``mark``.

    The snapshot is the same payload as ``OUT/snapshots/checkpoint_<agent-steps>.pt``.
    Returns the checkpoint's path and the next mark (see :func:`next_snapshot`).
    """
    payload = checkpoint_payload(run)
    path = save_checkpoint(out / CHECKPOINT, payload)
    if mark and run.agent_steps >= mark:
        save_checkpoint(out / SNAPSHOTS / snapshot_name(run.agent_steps), payload)
        mark = next_snapshot(run)
    return path, mark


def restore(run: Run, path: Path) -> None:
    """Continue from the checkpoint at ``path`` (same config required)."""
    payload = load_checkpoint(path, map_location=run.device)
    if "averaged_from" in payload:  # its weights are no state the optimizer ever saw
        raise CheckpointError(f"{path} is an average of {len(payload['averaged_from'])} "
                              f"checkpoints (collavn average), not a run's state: "
                              f"fine-tune it with --init-from {path} instead of resuming")
    check_config(payload, run.cfg, path)
    run.model.load_state_dict(payload["model"])
    run.optimizer.load_state_dict(payload["optimizer"])
    run.maps.optimizer.load_state_dict(payload["map_optimizer"])
    run.iteration, run.agent_steps = int(payload["iteration"]), int(payload["agent_steps"])


def out_of_budget(run: Run, stopping: bool = False) -> bool:
    """Total steps reached, budget spent, or ``stopping``; rank 0 decides for all.

    ``stopping``: a signal arrived and the run is at a sync point.
    """
    cfg = run.cfg
    done = stopping or run.agent_steps >= cfg.run.total_steps
    if cfg.run.time_budget_minutes > 0:
        done |= time.perf_counter() - run.started >= 60.0 * cfg.run.time_budget_minutes
    flag = distributed.all_reduce_mean([float(done) if run.info.is_main else 0.0],
                                       run.device)[0]
    return flag > 0


@dataclass(frozen=True)
class TrainResult:
    """What :func:`train` returns.

    Attributes:
        iterations: Updates done in total (including before a resume).
        agent_steps: Agent-steps collected in total (all processes).
        last: Scalars of the last update.
        checkpoint: Path of the final checkpoint (rank 0; ``None`` elsewhere).
        signal: The signal that stopped the run early (``signal.SIGINT``, …), or ``None``.
        moved: Where ``overwrite`` moved the old run directory, if it did.
    """

    iterations: int
    agent_steps: int
    last: dict[str, float]
    checkpoint: Path | None
    signal: int | None = None
    moved: Path | None = None


def train(cfg: TrainConfig) -> TrainResult:
    """Train ``cfg.method`` until ``total_steps``, the time budget or a signal.

    See the module doc (sync points, run directory) and
    :mod:`collavn.training.interrupt` (SIGINT / SIGTERM).

    Raises:
        ConfigError: ``out`` is not usable (see :func:`collavn.files.prepare_output_dir`).
        CheckpointError: ``resume`` (or ``resume_from``) without a checkpoint, or with
            another config's.
    """
    out = Path(cfg.run.out)
    if cfg.run.resume and not (out / CHECKPOINT).is_file():
        raise CheckpointError(f"--resume: no checkpoint at {out / CHECKPOINT}; check --out, "
                              f"or start a new run without --resume")
    source = Path(cfg.run.resume_from) if cfg.run.resume_from else None
    if source is not None and not source.is_file():
        raise CheckpointError(f"--resume-from: no checkpoint at {source}")
    info, device = distributed.setup(cfg.run.device)
    if cfg.run.torch_threads > 0:
        torch.set_num_threads(cfg.run.torch_threads)
    interval = cfg.run.checkpoint_interval
    try:
        moved = prepare_output_dir(out, resume=cfg.run.resume, overwrite=cfg.run.overwrite,
                                   create=info.is_main)
        with StopRequest(out / CHECKPOINT, interval) as stop:
            run = build_run(cfg, info, device)
            if cfg.run.resume or source is not None:
                restore(run, source or out / CHECKPOINT)
            logger = Logger(run, out) if info.is_main else None
            mark = next_snapshot(run)
            last: dict[str, float] = {}
            first = True
            while True:
                at_sync = first or run.iteration % interval == 0
                if out_of_budget(run, stopping=stop.requested and at_sync):
                    break
                if at_sync:
                    sync_point(run)
                    first = False
                tick = time.perf_counter()
                anneal_std(run)
                rollout, collected = collect_rollout(run)
                losses = learn(run, rollout)
                run.iteration += 1
                run.agent_steps += run.steps_per_update
                last = summary(run, collected, losses, time.perf_counter() - tick)
                if logger is not None:
                    logger.log(run, last)
                    if run.iteration % interval == 0:
                        _, mark = save_checkpoints(out, run, mark)
            path = None
            if logger is not None:
                path, _ = save_checkpoints(out, run, mark)
                logger.close()
        return TrainResult(run.iteration, run.agent_steps, last, path, stop.signum, moved)
    finally:
        distributed.cleanup()


class Logger:
    """Rank 0's outputs: ``config.json``, TensorBoard scalars, a progress bar.

    ``episode/*`` scalars average the last 200 agent-episodes that *ended*; short
    (successful) episodes end more often, so the training success rate over-states the
    rate per started episode. Score checkpoints with ``collavn evaluate`` on a dataset.
    """

    def __init__(self, run: Run, out: Path) -> None:
        from rich.progress import Progress
        from torch.utils.tensorboard import SummaryWriter

        out.mkdir(parents=True, exist_ok=True)
        (out / "config.json").write_text(json.dumps(run.cfg.to_dict(), indent=2) + "\n")
        self.writer = SummaryWriter(str(out), purge_step=run.iteration or None)
        self.interval = run.cfg.run.log_interval
        self.progress = Progress(disable=not run.cfg.run.progress)
        self.progress.start()
        self.task = self.progress.add_task(f"{run.cfg.method}", total=run.cfg.run.total_steps,
                                           completed=run.agent_steps)

    def log(self, run: Run, scalars: dict[str, float]) -> None:
        """Write the scalars of one update and advance the bar."""
        if run.iteration % self.interval == 0:
            for k, v in scalars.items():
                self.writer.add_scalar(k, v, run.agent_steps)
            self.writer.flush()
        sr = scalars.get("episode/success_rate", 0.0)
        self.progress.update(self.task, completed=run.agent_steps,
                             description=f"{run.cfg.method} upd {run.iteration} SR {sr:.2f} "
                             f"{scalars['perf/agent_steps_per_s']:.0f} st/s")

    def close(self) -> None:
        """Flush and stop."""
        self.writer.close()
        self.progress.stop()
