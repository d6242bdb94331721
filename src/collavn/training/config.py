"""Training configuration: one tree, each value stated once, two presets.

``TrainConfig = {method, env, model, ppo, mapping, imitation, run}``:

* ``env`` — :class:`~collavn.envs.config.EnvConfig`: task, agents, image sizes,
  difficulty of the on-the-fly episodes, renderer threads. The image sizes are stated
  here only; the model's input shapes and its communication variant are *derived*
  (from ``env`` and ``method``) when the config is built, and are not flags.
* ``model``, ``ppo``, ``mapping``, ``imitation`` — the learner.
* ``run`` — seeds, envs, scenes, budget, checkpoints, device, output directory.

The presets live in :mod:`collavn.training.presets`: ``paper`` (the paper's values:
ResNet18, 3×128×512 panoramas, 25 envs, 5 mini-batches, 8 epochs, Adam lr 1e-5, entropy
0.001, value coef 0.5, γ 0.99, a map FIFO of 5,000 samples with 10 updates of batch 64
per env step) and ``cpu`` (sized to learn something on a 2-core CPU), with the computed
differences between them and a reason for each.

The resolved config is written as ``config.json`` beside every run and inside every
checkpoint (:func:`collavn.configs.to_dict`; :meth:`TrainConfig.from_dict` refuses
unknown and missing keys). A checkpoint is only resumed by a run whose *identity* (every
field except :data:`RUN_CONTROL_FIELDS`) is equal.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Annotated, Any, Literal

import tyro

from collavn import configs
from collavn.configs import check_count, check_number
from collavn.envs.config import EnvConfig
from collavn.errors import ConfigError
from collavn.metrics import SIGHT_DISTANCE
from collavn.models.config import CommVariant, ModelConfig
from collavn.scenes.spec import LoadOptions
from collavn.scenes.splits import SPLIT_STRIDE

Method = Literal["ours", "no-mem", "no-com", "il"]
PresetName = Literal["paper", "cpu"]


@dataclass(frozen=True)
class MethodSpec:
    """What a learning method is made of.

    Attributes:
        comm: Communication variant of its model.
        imitation: Learns by imitating the shortest-path oracle (else decentralized PPO).
        description: One line for ``--help`` and reports.
    """

    comm: CommVariant
    imitation: bool
    description: str


#: The learning methods of the paper's table.
METHODS: dict[str, MethodSpec] = {
    "ours": MethodSpec("memory", False, "memory-augmented handshake communication, PPO"),
    "no-mem": MethodSpec("handshake", False, "handshake communication without memory, PPO"),
    "no-com": MethodSpec("none", False, "no communication (IPPO)"),
    "il": MethodSpec("none", True, "imitation of a privileged expert (DAgger / BC)"),
}

#: Fields that steer a run without changing its results (allowed to differ on resume).
RUN_CONTROL_FIELDS = ("run.out", "run.resume", "run.resume_from", "run.overwrite",
                      "run.total_steps", "run.time_budget_minutes", "run.snapshot_every",
                      "run.progress", "run.device", "run.log_interval", "run.torch_threads",
                      "env.render_threads", "run.encoder")


@dataclass(frozen=True)
class PPOConfig:
    """Decentralized PPO (clipped objective, value loss, entropy bonus)."""

    rollout_steps: int = 80
    """Env steps per rollout (T); an update sees ``T × E × N`` agent-steps."""
    num_minibatches: int = 5
    """Mini-batches per epoch; split over envs (whole sequences, all agents of an env)."""
    update_epochs: int = 8
    """Passes over each rollout."""
    lr: float = 1e-5
    """Adam learning rate."""
    gamma: float = 0.99
    """Discount γ."""
    gae_lambda: float = 0.95
    """GAE λ (the paper does not give it)."""
    clip_coef: float = 0.2
    """PPO ratio clip ε."""
    ent_coef: float = 0.001
    """Entropy bonus coefficient."""
    vf_coef: float = 0.5
    """Value loss coefficient."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip."""
    norm_adv: bool = True
    """Normalise advantages per mini-batch."""
    critic_warmup: int = 0
    """The first this-many updates of a run train only the critic (its GRU and value
    head; the policy, encoders and log-std stay fixed, the map module keeps its own
    supervised training) — for fine-tuning a policy from ``--init-from``, whose critic
    is untrained, without letting its noise move the policy."""
    target_kl: float = 0.0
    """Stop an update's epochs after the first whose mean approximate KL between the
    collecting and the updated policy exceeds this (0 = always run ``update_epochs``);
    keeps fine-tuning from ``--init-from`` near the policy it started from."""
    comm_lr_scale: float = 1.0
    """The communication parameters' learning rate (F_query, F_key, F_value, ψ) as a
    multiple of ``lr`` (1 = the same, 0 = frozen at their initial weights). At the full
    rate Adam's normalised steps move ψ's matrix coherently, every pair's score at once,
    and the gates drift shut (below η they get almost no gradient back); 0.1 kept them
    open in our runs (docs/learning-log.md, "Why the gates close")."""
    message_floor: float = 0.0
    """Keep messages flowing: the share p of agent-steps (those with an active teammate)
    in which a teammate's value should reach the agent (0 = off; methods that
    communicate). PPO's loss gains ``message_floor_coef × mean relu(τ − margin)`` over
    the ⌈p·n⌉ agent-steps of each mini-batch with the largest margin = min(s_{n,n},
    max_{m≠n} s_{n,m}) − η (> 0 exactly when a message arrives; τ the gate's
    temperature): when fewer than p of them hear a teammate, the ones closest to hearing
    are pushed over η. Which steps talk stays the policy's choice; only the rate is held
    up. Without it the gates drift shut during PPO, and a closed gate's straight-through
    gradient (σ' at (s − η)/τ ≈ −9, ~10⁻⁴) cannot reopen it (docs/learning-log.md, "Why
    the gates close")."""
    message_floor_coef: float = 1.0
    """Weight of the message floor's term in PPO's loss."""
    bc_coef: float = 0.0
    """Weight of a behaviour-cloning term in PPO's loss: the negative log-likelihood of
    the expert's action (``--imitation.expert``, ``--imitation.sight``) in every state PPO
    visits, under the policy's means with its σ held fixed (0 = plain PPO). The expert
    runs beside the policy during collection, on privileged observations the policy
    never reads. Meant to keep the mean action of a policy fine-tuned from an ``il``
    checkpoint near what it imitated while the reward pulls it on: PPO's reward
    (progress along the geodesic) does not pay for the search the expert does before
    the goal is in sight."""
    bc_decay: float = 1.0
    """The behaviour-cloning weight is ``bc_coef × bc_decay ** update`` (1 = constant)."""
    bc_target: Literal["expert", "init"] = "expert"
    """Whose actions the behaviour-cloning term imitates: ``expert`` (the expert above,
    run beside the policy) or ``init`` (the ``--init-from`` policy's own mean action, a
    frozen copy replayed over each rollout's stored features with its own recurrent
    state: an anchor that keeps the fine-tuned mean action near the one it started from
    where the reward does not pay to move it; no expert, no privileged observations)."""
    bc_steps: Literal["all", "sighted", "blocked"] = "all"
    """The steps the behaviour-cloning term weighs: ``all`` active steps; ``sighted``
    ones only — after the agent's goal has been in sight this episode (within
    ``--imitation.sight`` metres along a navigable straight line, the seeker's switch and
    the evaluation's ``goal sighted``; the trainer reads the privileged poses for this,
    the policy never does); or ``blocked`` ones only — the ``--ppo.bc-blocked-window``
    steps after one on which the agent collided, in the same episode (the trainer reads
    the env's collision flags, as it reads the reward). With ``--ppo.bc-target init``,
    ``sighted`` anchors the homing the ``--init-from`` policy learnt and leaves PPO free
    to change how it searches; ``blocked`` anchors how it gets away from what it drove
    into and leaves PPO free everywhere else. The term stays a mean over all active
    steps (the others add 0), so ``--ppo.bc-coef`` pulls each weighed step as hard as
    with ``all``."""
    bc_blocked_window: int = 3
    """With ``--ppo.bc-steps blocked``: a step weighs when the agent collided on one of
    the this-many steps before it (1 = only the step right after a collision)."""
    start_std: float = 0.0
    """Set the policy's σ (every action dimension) to this when a run starts, after
    ``--init-from`` (0 = keep the model's initial or the checkpoint's σ; a resumed run
    keeps its own). PPO improves the policy whose actions it samples, but the policy is
    scored by its mean action; from an ``il`` checkpoint (σ ≈ 0.35, on actions in
    [−1, 1]) the two drive differently, and a small σ keeps PPO's samples near the mean
    it will be scored on."""
    end_std: float = 0.0
    """Anneal σ instead of learning it (0 = learn it, as before): σ goes from
    ``--ppo.start-std`` at agent-step 0 to this at ``--total-steps``, geometrically (log σ
    linear in the agent-steps), set before every rollout; the log-std is then not a
    trained weight. PPO improves the smoothed return of the policy it samples, the
    mean action is scored on the unsmoothed one; a σ that shrinks through the run lets
    the early updates explore and the late ones improve a policy that drives almost as
    its mean does. Needs ``--ppo.start-std``; a resumed run follows the same schedule (it
    depends on the agent-steps and ``--total-steps`` only: extending a run with a larger
    ``--total-steps`` stretches it). Measured (docs/learning-log.md, 2026-12-07): 0.15 →
    0.05 over 368,640 agent-steps collapsed an ``ours`` run from ``il`` (mean-action SR 0.39
    / 0.21 easy / medium against 0.58 / 0.36 for the same seed with σ learned): Adam moves
    the means by about the learning rate per step whatever σ is, so each update's KL grows
    as 1/σ² (0.010 → 0.020, past ``--ppo.target-kl``, clip fraction 0.09 → 0.17)."""

    def __post_init__(self) -> None:
        check_number("--ppo.target-kl", self.target_kl, allow_minimum=True)
        check_number("--ppo.bc-coef", self.bc_coef, allow_minimum=True)
        check_number("--ppo.bc-decay", self.bc_decay)
        check_number("--ppo.start-std", self.start_std, allow_minimum=True)
        check_number("--ppo.end-std", self.end_std, allow_minimum=True)
        if self.end_std > 0 and self.start_std <= 0:
            raise ConfigError(f"--ppo.end-std {self.end_std} anneals σ from --ppo.start-std: "
                              f"give --ppo.start-std too")
        if self.bc_target not in ("expert", "init"):
            raise ConfigError(f"--ppo.bc-target must be expert or init, got {self.bc_target!r}")
        if self.bc_steps not in ("all", "sighted", "blocked"):
            raise ConfigError(f"--ppo.bc-steps must be all, sighted or blocked, got "
                              f"{self.bc_steps!r}")
        check_count("--ppo.bc-blocked-window", self.bc_blocked_window)
        if self.bc_decay > 1:
            raise ConfigError(f"--ppo.bc-decay must be in (0, 1], got {self.bc_decay}")
        check_number("--ppo.comm-lr-scale", self.comm_lr_scale, allow_minimum=True)
        check_number("--ppo.message-floor", self.message_floor, allow_minimum=True)
        if self.message_floor > 1:
            raise ConfigError(f"--ppo.message-floor is a share of agent-steps in [0, 1], "
                              f"got {self.message_floor}")
        check_number("--ppo.message-floor-coef", self.message_floor_coef, allow_minimum=True)
        for name in ("rollout_steps", "num_minibatches", "update_epochs"):
            check_count(f"--ppo.{name.replace('_', '-')}", getattr(self, name))
        check_count("--ppo.critic-warmup", self.critic_warmup, 0)
        for name in ("lr", "clip_coef", "max_grad_norm"):
            check_number(f"--ppo.{name.replace('_', '-')}", getattr(self, name))
        for name in ("ent_coef", "vf_coef"):
            check_number(f"--ppo.{name.replace('_', '-')}", getattr(self, name),
                         allow_minimum=True)
        check_number("--ppo.gamma", self.gamma)
        if self.gamma > 1:
            raise ConfigError(f"--ppo.gamma must be in (0, 1], got {self.gamma}")
        check_number("--ppo.gae-lambda", self.gae_lambda, allow_minimum=True)
        if self.gae_lambda > 1:
            raise ConfigError(f"--ppo.gae-lambda must be in [0, 1], got {self.gae_lambda}")


@dataclass(frozen=True)
class MapTrainConfig:
    """Supervised training of the map predictor from a FIFO of (panorama, gt_map) samples."""

    fifo_size: int = 5000
    """Samples kept (oldest dropped first)."""
    updates: int = 10
    """Gradient steps each time the map is trained."""
    batch_size: int = 64
    """Samples per gradient step."""
    every: int = 1
    """Train the map every this many env steps (paper: every step)."""
    lr: float = 1e-4
    """Adam learning rate of the map predictor."""
    enabled: bool = True
    """Train the map module at all (off: the map input stays at its random init)."""

    def __post_init__(self) -> None:
        for name in ("fifo_size", "batch_size", "every"):
            check_count(f"--mapping.{name.replace('_', '-')}", getattr(self, name))
        check_count("--mapping.updates", self.updates, 0)
        check_number("--mapping.lr", self.lr)


@dataclass(frozen=True)
class ImitationConfig:
    """Imitation of a privileged expert, the shortest-path oracle by default (method ``il``)."""

    expert: Literal["oracle", "seeker"] = "oracle"
    """Whom ``il`` imitates (and PPO's ``--ppo.bc-coef`` term): ``oracle``, the shortest
    path from the first step (the paper's baseline); ``seeker``, the explorer's moves
    (deterministic) until the goal is in sight, then the oracle's — every move inferable
    from what the agent sees (see :mod:`collavn.policies.seeker`)."""
    sight: float = SIGHT_DISTANCE
    """``seeker`` only: the goal is in sight within this many metres along a navigable
    straight line."""
    dagger: bool = False
    """DAgger: let the learner drive (with its mean action, the policy that is evaluated)
    with probability ``1 - β`` (else pure BC)."""
    beta_decay: float = 0.95
    """β = ``beta_decay ** iteration`` when ``dagger`` (β = 1: the expert always drives)."""
    beta_min: float = 0.1
    """Lower bound of β."""
    epochs: int = 2
    """Passes over the kept rollouts per update."""
    buffer_rollouts: int = 1
    """Aggregate the last this-many rollouts (DAgger's growing data set, bounded); 1 = the
    fresh rollout only. Cleared at checkpoint sync points."""
    num_minibatches: int = 2
    """Mini-batches per epoch (split over envs)."""
    lr: float = 3e-4
    """Adam learning rate."""
    belief_coef: float = 1.0
    """Weight of the goal-belief head's loss (only with ``--model.goal-belief K``)."""
    homing_weight: float = 1.0
    """``seeker`` only: weight of the steps where the expert is homing (the goal has been
    in sight) against 1 for its searching steps, in the likelihood's weighted mean. A
    learner that cannot tell whether the goal is in sight averages "explore on" and "turn
    to the goal"; weighting the homing steps makes missing a goal cost more than a
    needless turn towards one."""
    lr_decay: bool = False
    """Decay the learning rate linearly from ``lr`` to 0 at ``--total-steps`` (by
    agent-steps, so a seed gives the same schedule on any machine; a time budget that
    stops the run earlier leaves it part-way)."""

    def __post_init__(self) -> None:
        for name in ("epochs", "buffer_rollouts", "num_minibatches"):
            check_count(f"--imitation.{name.replace('_', '-')}", getattr(self, name))
        check_number("--imitation.lr", self.lr)
        check_number("--imitation.sight", self.sight)
        check_number("--imitation.belief-coef", self.belief_coef, allow_minimum=True)
        check_number("--imitation.homing-weight", self.homing_weight)
        if self.expert not in ("oracle", "seeker"):
            raise ConfigError(f"--imitation.expert must be oracle or seeker, got {self.expert!r}")
        if self.homing_weight != 1.0 and self.expert != "seeker":
            raise ConfigError("--imitation.homing-weight needs --imitation.expert seeker (the "
                              "oracle homes from the first step: there is no search to weigh "
                              f"against), got {self.expert!r}")
        for name in ("beta_decay", "beta_min"):
            value = getattr(self, name)
            check_number(f"--imitation.{name.replace('_', '-')}", value, allow_minimum=True)
            if value > 1:
                raise ConfigError(f"--imitation.{name.replace('_', '-')} must be in [0, 1], "
                                  f"got {value}")


@dataclass(frozen=True)
class RunConfig:
    """How a run is executed: seeds, envs, scenes, budget, checkpoints, output."""

    out: str = "runs/train"
    """Run directory: ``config.json``, ``checkpoint.pt``, TensorBoard events."""
    resume: bool = False
    """Continue from ``OUT/checkpoint.pt`` (refused if it is missing or was made by
    another config)."""
    resume_from: str = ""
    """Continue the checkpoint of another run in a new ``OUT`` (its directory is left as it
    is), e.g. to extend a finished run with a larger ``--total-steps`` and keep the
    original. The checkpoint's config must match this run's, as for ``--resume``; the
    new run then goes on exactly as the old one would have (TensorBoard starts afresh in
    ``OUT``). To continue again after a stop, use ``--resume`` on ``OUT``."""
    overwrite: bool = False
    """Start over in a non-empty ``OUT``: the old directory is moved aside to
    ``OUT.old-<time>`` (nothing is deleted). Without it (or ``--resume``) a non-empty
    ``OUT`` is refused."""
    seed: int = 0
    """Base seed; process ``r`` uses ``seed + 1000·r`` for its envs and sampling."""
    num_envs: int = 25
    """Envs per process; env ``i`` lives in scene ``i mod #scenes`` of the process."""
    scenes: tuple[str, ...] = ()
    """Scene specs to train on; empty = the first ``train_scenes`` procedural ``train``
    scenes."""
    train_scenes: int = 25
    """How many procedural ``train`` scenes (seeds 0 … N − 1 of the train range) a run
    without ``--scenes`` trains in: the paper's split has 25. More cost nothing to make
    (generated from their seeds, then cached); ``collavn pretrain`` uses 100 of the same
    range. (Measured for ``il``, ``cpu`` preset: 100 scored no better on val than 25.)"""
    load: Annotated[LoadOptions, tyro.conf.OmitArgPrefixes] = field(default_factory=LoadOptions)
    """How to load mesh files in ``scenes`` (``--up-axis``, ``--scale``,
    ``--floor-height``)."""
    total_steps: int = 10_000_000
    """Stop after this many agent-steps (summed over processes)."""
    time_budget_minutes: float = 0.0
    """Stop (with a checkpoint) after this wall-clock time; 0 = no limit (negative is
    refused)."""
    checkpoint_interval: int = 10
    """Updates between checkpoints; checkpoints are sync points (envs reset, FIFO cleared)."""
    snapshot_every: int = 0
    """Also keep the checkpoint each time the run passes a multiple of this many
    agent-steps, as ``OUT/snapshots/checkpoint_<agent-steps>.pt`` (written at the next
    checkpoint, so the steps in the name may exceed the multiple): a learning curve to
    score with ``collavn evaluate --policy``, or weights to average with ``collavn
    average``. 0 = keep only the latest checkpoint."""
    log_interval: int = 1
    """Write TensorBoard scalars every this many updates."""
    device: str = "cpu"
    """Torch device (``cpu``, ``cuda``; under torchrun ``cuda`` means ``cuda:LOCAL_RANK``)."""
    torch_threads: int = 0
    """torch threads per process; 0 = automatic: one torch, inter-op and Numba thread
    (two runs can share two cores; see :mod:`collavn.threads`)."""
    progress: bool = True
    """Show a progress bar (rank 0)."""
    init_from: str = ""
    """Start from the model weights of this checkpoint (e.g. an ``il`` run's, to
    fine-tune it with PPO); its model config must match, except that a checkpoint
    without communication may start ``ours`` / ``no-mem`` (message inputs start at zero
    weight: the first policy is the checkpoint's). Optimizers start fresh."""

    encoder: str = ""
    """A pretrained frame perception (``collavn pretrain`` → ``encoder.pt``), frozen: it
    runs once per env step during collection, the rollout stores its features, and PPO
    epochs and imitation updates never run it again. Empty = learn from pixels."""
    encoder_sha256: str = ""
    """Checksum of the ``encoder`` file, filled in by the run and saved with its config
    (a resume refuses another file); give it to insist on one file."""

    def __post_init__(self) -> None:
        for name in ("num_envs", "total_steps", "checkpoint_interval", "log_interval",
                     "train_scenes"):
            check_count(f"--{name.replace('_', '-')}", getattr(self, name))
        if self.train_scenes > SPLIT_STRIDE:
            raise ConfigError(f"--train-scenes must be at most {SPLIT_STRIDE} (the size of "
                              f"the train seed range), got {self.train_scenes}")
        check_count("--seed", self.seed, 0)
        check_count("--torch-threads", self.torch_threads, 0)
        check_count("--snapshot-every", self.snapshot_every, 0)
        check_number("--time-budget-minutes", self.time_budget_minutes, allow_minimum=True)
        if self.resume and self.overwrite:
            raise ConfigError("--resume and --overwrite exclude each other: continue the "
                              "run or start it over")
        if self.resume_from and self.resume:
            raise ConfigError("--resume and --resume-from exclude each other: --resume "
                              "continues OUT's own checkpoint, --resume-from another run's")
        if self.resume_from and Path(self.out).resolve() in Path(self.resume_from).resolve(
                ).parents:
            raise ConfigError(f"--resume-from {self.resume_from} lies inside --out "
                              f"{self.out}: continue that run in place with --resume")


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on (a preset plus overrides)."""

    method: Method = "ours"
    """``ours`` (memory communication), ``no-mem`` (handshake), ``no-com`` (IPPO), ``il``."""
    preset: Annotated[PresetName, tyro.conf.Suppress] = "paper"
    """The preset this config started from (informational)."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """What the agents sense, the task and the on-the-fly episodes."""
    model: ModelConfig = field(default_factory=ModelConfig.paper)
    """The agent model (input shapes and communication variant derived from env, method)."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    """PPO settings (also the rollout length for ``il``)."""
    mapping: MapTrainConfig = field(default_factory=MapTrainConfig)
    """Map module training."""
    imitation: ImitationConfig = field(default_factory=ImitationConfig)
    """Imitation settings (method ``il``)."""
    run: Annotated[RunConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=RunConfig)
    """Seeds, envs, budget, checkpoints, output (flags without a prefix: ``--out``)."""

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(f"unknown method {self.method!r}; expected one of "
                              f"{', '.join(METHODS)}")
        # Derived, never stated twice: the model's inputs follow the env, its
        # communication the method.
        model = replace(self.model,
                        panorama_shape=(3, self.env.panorama_height, self.env.panorama_width),
                        goal_shape=(3, self.env.goal_size, self.env.goal_size),
                        comm=replace(self.model.comm, variant=self.method_spec.comm))
        object.__setattr__(self, "model", model)
        if self.ppo.message_floor > 0 and (self.method_spec.imitation
                                           or self.method_spec.comm == "none"):
            raise ConfigError(f"--ppo.message-floor keeps PPO's messages flowing; method "
                              f"{self.method!r} sends none (use ours or no-mem)")
        if not self.model.comm.listen and self.method_spec.comm == "none":
            raise ConfigError(f"--model.comm.no-listen cuts the links between teammates; "
                              f"method {self.method!r} has none (use ours or no-mem)")
        comm = self.model.comm
        for hears, who in ((comm.critic_hears, "critic"), (comm.actor_hears, "actor")):
            if not hears and (self.method_spec.comm == "none" or not comm.listen):
                raise ConfigError(f"--model.comm.no-{who}-hears keeps teammates' entries "
                                  f"from the {who}; method {self.method!r} "
                                  + ("has none" if self.method_spec.comm == "none" else
                                     "with --model.comm.no-listen hears none already")
                                  + " (use ours or no-mem, listening)")
        if not (comm.critic_hears or comm.actor_hears):
            raise ConfigError("--model.comm.no-critic-hears with --model.comm.no-actor-hears"
                              " hears no teammate: that is --model.comm.no-listen")
        if not self.model.comm.listen and self.ppo.message_floor > 0:
            raise ConfigError("--ppo.message-floor pushes agents to hear a teammate; "
                              "--model.comm.no-listen cuts every link (use one of them)")
        if self.ppo.end_std > 0 and self.method_spec.imitation:
            raise ConfigError("--ppo.end-std anneals PPO's σ; method 'il' learns its σ by "
                              "likelihood (leave --ppo.end-std at 0)")
        if self.ppo_clones and self.ppo.bc_target == "init" and not self.run.init_from:
            raise ConfigError("--ppo.bc-target init imitates the --init-from policy: give "
                              "--init-from CHECKPOINT (or use --ppo.bc-target expert)")

    @property
    def method_spec(self) -> MethodSpec:
        """What ``method`` is made of."""
        return METHODS[self.method]

    @property
    def ppo_clones(self) -> bool:
        """PPO's loss has a behaviour-cloning term (``--ppo.bc-coef`` > 0, not ``il``)."""
        return not self.method_spec.imitation and self.ppo.bc_coef > 0

    @property
    def learning_rate(self) -> float:
        """The policy optimizer's learning rate (imitation's for ``il``, else PPO's)."""
        return self.imitation.lr if self.method_spec.imitation else self.ppo.lr

    def with_run(self, **changes: Any) -> TrainConfig:
        """A copy with fields of ``run`` replaced (``cfg.with_run(out="x", resume=True)``)."""
        return replace(self, run=replace(self.run, **changes))

    def with_env(self, **changes: Any) -> TrainConfig:
        """A copy with fields of ``env`` replaced (the model's shapes follow)."""
        return replace(self, env=replace(self.env, **changes))

    def identity(self) -> dict[str, Any]:
        """The fields that must match to resume a checkpoint."""
        d = self.to_dict()
        for path in RUN_CONTROL_FIELDS:
            section, name = path.split(".")
            d[section].pop(name)
        return d

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible dict (tuples become lists); :meth:`from_dict` inverts it."""
        return configs.to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of :meth:`to_dict`; unknown or missing keys are errors."""
        return configs.from_dict(cls, d)
