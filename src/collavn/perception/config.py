"""Configuration of perception pretraining (``collavn pretrain``).

``PretrainConfig = {preset, env, model, perception, run fields}``. ``env`` and ``model``
are the training config's own sections (a preset takes them from the ``train`` preset of
the same name), so an encoder pretrained with ``--preset cpu`` fits ``collavn train
--preset cpu``: only the image sizes and camera height of ``env`` and the frame
perception of ``model`` (:func:`collavn.models.frames.frame_spec`) are used, and those
are what the encoder file records and a training run checks.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Annotated, Any, Literal

import tyro

from collavn import configs
from collavn.envs.config import EnvConfig
from collavn.errors import ConfigError
from collavn.models.config import ModelConfig


@dataclass(frozen=True)
class PerceptionConfig:
    """Frames, labels and optimisation of the pretraining."""

    train_scenes: int = 100
    """Procedural training scenes (seeds 0 … train_scenes − 1 of the train range) when no
    ``--scenes`` are given. More than the 25 a policy trains in: rendering and labelling
    100 scenes took 2.5 min of a 15-min run here (cached scenes; generating one costs
    ~0.4 s more), and the held-out loss falls with the variety of rooms (15 min: 4.79
    with 25 scenes × 16 goals, 4.52 with 100 × 32)."""
    frames_per_scene: int = 256
    """Panoramas rendered per training scene (the set is rendered once, then reused with
    random rotations and mirror images)."""
    goals_per_scene: int = 32
    """Goal images per scene; every panorama is labelled against every goal of its scene."""
    val_frames_per_scene: int = 64
    """Panoramas per validation scene (held-out accuracy)."""
    near_distance: float = 10.0
    """Panoramas are taken within this geodesic distance of one of the scene's goals
    (density ∝ 1/distance: near the goal as often as far)."""
    own_goal_fraction: float = 0.5
    """Fraction of pairs that use the goal a panorama was sampled near (else another goal
    of the same scene, usually far or round corners)."""
    bins: int = 16
    """Azimuth sectors of the bearing and free-space labels (divides the panorama width)."""
    max_free: float = 4.0
    """Free-space labels are capped at this many metres."""
    max_distance: float = 15.0
    """Geodesic distance labels are capped at this many metres."""
    steps: int = 20_000
    """Gradient steps (unless the time budget ends first)."""
    batch_size: int = 64
    """Pairs per step."""
    lr: float = 1e-3
    """Adam learning rate."""
    hidden: int = 256
    """Width of the pair head (discarded after pretraining)."""
    mirror: bool = True
    """Also train on mirror images (panorama and goal flipped, bearings mirrored)."""
    ema: float = 0.999
    """Decay of a (bias-corrected) exponential moving average of the weights and
    BatchNorm statistics; 0 = off. The held-out scores and ``encoder.pt`` are the
    average's; the trained weights' held-out scores are logged beside them
    (``val_raw/*``). At a constant learning rate the weights wander from step to step
    (the held-out path accuracy at easy distances of one run moved between 0.47 and 0.60
    over 2,000 steps); the average of the last ~1,000 steps does not. Measured, same run
    (2026-12-05, ``--preset cpu``, 1 thread): held-out loss 4.365 against 4.431 at 9,000
    steps, 4.347 against 4.519 at 12,500, lower at every evaluation from step 3,500 on."""

    def __post_init__(self) -> None:
        if min(self.train_scenes, self.frames_per_scene, self.goals_per_scene,
               self.val_frames_per_scene, self.bins, self.steps, self.batch_size) < 1:
            raise ConfigError("scenes, frames, goals, bins, steps and batch size must be ≥ 1")
        if not 0.0 <= self.ema < 1.0:
            raise ConfigError(f"--perception.ema must be in [0, 1), got {self.ema}")
        if not 0.0 <= self.own_goal_fraction <= 1.0:
            raise ConfigError(f"own_goal_fraction must be in [0, 1], got "
                              f"{self.own_goal_fraction}")


@dataclass(frozen=True)
class PretrainConfig:
    """Everything a pretraining run depends on."""

    preset: Annotated[Literal["paper", "cpu"], tyro.conf.Suppress] = "cpu"
    """The preset this config started from (informational)."""
    env: EnvConfig = field(default_factory=EnvConfig)
    """Image sizes, camera height and renderer (the rest is not used here)."""
    model: ModelConfig = field(default_factory=ModelConfig.cpu)
    """The frame perception to pretrain: encoder, embed_dim, goal_match (the rest is not
    used here)."""
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)
    """Frames, labels and optimisation."""
    out: str = "runs/pretrain"
    """Output directory: ``encoder.pt``, ``config.json``, TensorBoard events."""
    seed: int = 0
    """Seeds the frames, the pairs and the initial weights."""
    scenes: tuple[str, ...] = ()
    """Training scene specs; empty = ``perception.train_scenes`` procedural ``train``
    scenes."""
    val_scenes: tuple[str, ...] = ()
    """Held-out scene specs; empty = the 5 procedural ``val`` scenes."""
    time_budget_minutes: float = 0.0
    """Stop (and save) after this wall-clock time, rendering included; 0 = no limit."""
    eval_interval: int = 500
    """Steps between held-out evaluations (and the last step)."""
    log_interval: int = 50
    """Steps between TensorBoard scalars."""
    torch_threads: int = 0
    """``torch.set_num_threads`` (0 = automatic, see :mod:`collavn.training.threads`)."""
    progress: bool = True
    """Show a progress bar."""

    def __post_init__(self) -> None:
        if self.env.panorama_width % self.perception.bins:
            raise ConfigError(f"panorama width {self.env.panorama_width} is not a multiple "
                              f"of perception.bins {self.perception.bins}")
        r, p = self.model.readout, self.perception
        if r.enabled and (r.bins, r.hidden) != (p.bins, p.hidden):
            raise ConfigError(f"model.readout (bins {r.bins}, hidden {r.hidden}) is trained "
                              f"here as the label heads: set perception.bins/hidden to the "
                              f"same (now {p.bins}, {p.hidden})")
        model = replace(self.model,
                        panorama_shape=(3, self.env.panorama_height, self.env.panorama_width),
                        goal_shape=(3, self.env.goal_size, self.env.goal_size))
        object.__setattr__(self, "model", model)

    def to_dict(self) -> dict[str, Any]:
        """JSON-compatible dict; :meth:`from_dict` inverts it."""
        return configs.to_dict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PretrainConfig:
        """Inverse of :meth:`to_dict`; unknown or missing keys are errors."""
        return configs.from_dict(cls, d)
