"""Training configuration: one resolved :class:`TrainConfig` per run, with two presets.

``TrainConfig.preset("paper", ...)`` keeps the paper's values (ResNet18, 3×128×512
panoramas, 25 envs, 5 mini-batches, 8 epochs, Adam lr 1e-5, entropy 0.001, value coef
0.5, γ 0.99, a map FIFO of 5,000 samples with 10 updates of batch 64 per env step).
``TrainConfig.preset("cpu", ...)`` is sized to learn something on a 2-core CPU; its
deviations from the paper are listed in :data:`CPU_DEVIATIONS` and in the docs.

The resolved config is written as ``config.json`` beside every run and inside every
checkpoint; a checkpoint is only resumed by a run whose *identity* (every field except
:data:`RUN_CONTROL_FIELDS`) is equal.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import asdict, dataclass, field, replace
from typing import Any, Literal

from collavn.errors import CollavnError
from collavn.models.config import CommConfig, MapConfig, MatchConfig, ModelConfig

Method = Literal["ours", "no-mem", "no-com", "il"]
Preset = Literal["paper", "cpu"]

#: Communication variant of each learning method.
METHOD_COMM: dict[str, str] = {"ours": "memory", "no-mem": "handshake", "no-com": "none",
                               "il": "none"}

#: Fields that steer a run without changing its results (allowed to differ on resume).
RUN_CONTROL_FIELDS = ("out", "total_steps", "time_budget_minutes", "progress", "device",
                      "log_interval")

#: How the ``cpu`` preset departs from the paper, and why.
CPU_DEVIATIONS: dict[str, str] = {
    "model": "small CNN, 256-d embeddings, 3×32×128 panoramas, 32×32 goals, 96×96 map at "
             "20 cm (ModelConfig.cpu) — ResNet18 at 512×128 runs ~30 images/s on 2 cores",
    "goal_match": "goal matching on (collavn.models.matching): the goal image is compared "
                  "with the panorama at every azimuth and 3 scales, instead of leaving a "
                  "GRU to learn the comparison from two pooled embeddings",
    "odometry": "the last step's pose change is a direct policy input (odometry_input), "
                "so a robot pushing against a wall can tell that it is not moving",
    "critic": "the critic also sees the map and goal vectors (critic_full_input); the "
              "paper's V sees only (O, ω), which cannot tell how far the goal is",
    "num_envs": "8 envs (not 25) to fit 2 cores; they move on to the next 8 training "
                "scenes at every checkpoint sync point",
    "lr": "1e-3 (not 1e-5): 1e-5 (and 3e-4: approx-KL < 5e-4 per update) moves the "
          "policy too little in the ~1e5 agent-steps an hour gives",
    "update_epochs": "4 epochs × 2 mini-batches (not 8 × 5): the update dominates CPU time",
    "map": "2 map updates of batch 32 once per rollout (not 10 × 64 every env step)",
    "difficulty": "easy episodes on the fly (the paper trains on its fixed mixed dataset)",
    "il": "DAgger on by default (β = 0.95^update, ≥ 0.1) over the last 8 rollouts; the "
          "paper's IL is plain BC",
}


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


@dataclass(frozen=True)
class ImitationConfig:
    """Behaviour cloning of the shortest-path oracle (method ``il``)."""

    dagger: bool = False
    """DAgger: let the learner drive with probability ``1 - β`` (else pure BC)."""
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


@dataclass(frozen=True)
class TrainConfig:
    """Everything a training run depends on (the resolved preset plus overrides)."""

    method: Method = "ours"
    """``ours`` (memory communication), ``no-mem`` (handshake), ``no-com`` (IPPO), ``il``."""
    task: str = "commongoal"
    """``commongoal``, ``specificgoal`` or ``adhocoop``."""
    agents: int = 2
    """Agents per env during training."""
    difficulty: str = "mixed"
    """Difficulty of the on-the-fly training episodes (easy, medium, hard, mixed)."""
    preset: Preset = "paper"
    """The preset this config was resolved from (informational)."""
    num_envs: int = 25
    """Envs per process; env ``i`` lives in scene ``i mod #scenes`` of the process."""
    scenes: tuple[str, ...] = ()
    """Scene specs to train on; empty = the 25 procedural ``train`` scenes."""
    panorama_width: int = 512
    """Panorama width in pixels."""
    panorama_height: int = 128
    """Panorama height in pixels."""
    goal_size: int = 128
    """Goal image side."""
    render_threads: int = 2
    """Renderer threads per process."""
    torch_threads: int = 0
    """``torch.set_num_threads`` per process (0 = leave torch's default)."""
    model: ModelConfig = field(default_factory=ModelConfig.paper)
    """The agent model."""
    ppo: PPOConfig = field(default_factory=PPOConfig)
    """PPO settings (also the rollout length for ``il``)."""
    mapping: MapTrainConfig = field(default_factory=MapTrainConfig)
    """Map module training."""
    imitation: ImitationConfig = field(default_factory=ImitationConfig)
    """Imitation settings (method ``il``)."""
    seed: int = 0
    """Base seed; process ``r`` uses ``seed + 1000·r`` for its envs and sampling."""
    checkpoint_interval: int = 10
    """Updates between checkpoints; checkpoints are sync points (envs reset, FIFO cleared)."""
    out: str = "runs/train"
    """Run directory: ``config.json``, ``checkpoint.pt``, TensorBoard events."""
    total_steps: int = 10_000_000
    """Stop after this many agent-steps (summed over processes)."""
    time_budget_minutes: float = 0.0
    """Stop (with a checkpoint) after this wall-clock time; 0 = no limit."""
    device: str = "cpu"
    """Torch device (``cpu``, ``cuda``; under torchrun ``cuda`` means ``cuda:LOCAL_RANK``)."""
    progress: bool = True
    """Show a progress bar (rank 0)."""
    log_interval: int = 1
    """Write TensorBoard scalars every this many updates."""
    init_from: str = ""
    """Start from the model weights of this checkpoint (e.g. an ``il`` run's, to
    fine-tune it with PPO); its model config must match. Optimizers start fresh."""

    def __post_init__(self) -> None:
        if self.method not in METHOD_COMM:
            raise CollavnError(f"unknown method {self.method!r}; expected one of "
                               f"{', '.join(METHOD_COMM)}")
        if self.num_envs < 1 or self.agents < 1 or self.ppo.rollout_steps < 1:
            raise CollavnError("num_envs, agents and rollout_steps must be ≥ 1")
        if self.ppo.critic_warmup < 0:
            raise CollavnError(f"critic_warmup must be ≥ 0, got {self.ppo.critic_warmup}")

    @classmethod
    def preset_config(cls, name: str, **overrides: Any) -> TrainConfig:
        """The ``paper`` or ``cpu`` preset with ``overrides`` applied (top-level fields)."""
        if name == "paper":
            base = cls(preset="paper")
        elif name == "cpu":
            base = cls(
                preset="cpu", difficulty="easy", num_envs=8, panorama_width=128,
                panorama_height=32, goal_size=32, render_threads=1, checkpoint_interval=20,
                model=ModelConfig.cpu(map=replace(ModelConfig.cpu().map, hidden=128)),
                ppo=PPOConfig(rollout_steps=32, num_minibatches=2, update_epochs=4, lr=1e-3),
                mapping=MapTrainConfig(updates=2, batch_size=32, every=32, lr=3e-4),
                imitation=ImitationConfig(dagger=True, buffer_rollouts=8, epochs=1))
        else:
            raise CollavnError(f"unknown preset {name!r}; expected paper or cpu")
        return replace(base, **overrides).resolved()

    def resolved(self) -> TrainConfig:
        """Make the model agree with the run: comm variant from ``method``, image shapes."""
        comm = replace(self.model.comm, variant=METHOD_COMM[self.method])  # type: ignore[arg-type]
        model = replace(self.model, comm=comm,
                        panorama_shape=(3, self.panorama_height, self.panorama_width),
                        goal_shape=(3, self.goal_size, self.goal_size))
        return replace(self, model=model)

    def identity(self) -> dict[str, Any]:
        """The fields that must match to resume a checkpoint."""
        d = self.to_dict()
        for name in RUN_CONTROL_FIELDS:
            d.pop(name)
        return d

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible dict (tuples become lists)."""
        return json.loads(json.dumps(asdict(self)))

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        """Inverse of :meth:`to_dict`."""
        d = dict(d)
        d["scenes"] = tuple(d.get("scenes", ()))
        d["model"] = model_config_from_dict(d["model"])
        d["ppo"] = PPOConfig(**d["ppo"])
        d["mapping"] = MapTrainConfig(**d["mapping"])
        d["imitation"] = ImitationConfig(**d["imitation"])
        return cls(**d)


def model_config_from_dict(d: dict[str, Any]) -> ModelConfig:
    """Rebuild a :class:`ModelConfig` from ``asdict`` output (lists → tuples)."""
    d = dict(d)
    d["map"] = MapConfig(**d["map"])
    comm_fields = {f.name for f in dataclasses.fields(CommConfig)}  # ``gate`` was retired
    d["comm"] = CommConfig(**{k: v for k, v in d["comm"].items() if k in comm_fields})
    match = dict(d.get("goal_match", {}))  # absent in runs saved before it existed: off
    if "scales" in match:
        match["scales"] = tuple(match["scales"])
    d["goal_match"] = MatchConfig(**match)
    for name in ("panorama_shape", "goal_shape"):
        d[name] = tuple(d[name])
    known = {f.name for f in dataclasses.fields(ModelConfig)}
    return ModelConfig(**{k: v for k, v in d.items() if k in known})

