"""The ``paper`` and ``cpu`` training presets, how they differ and why, and their parser.

Each preset is a whole :class:`~collavn.training.config.TrainConfig`; the command line
(:func:`parse_train_args`) applies one through tyro's overridable configs.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import replace
from typing import Any

from collavn import configs
from collavn.envs.config import EnvConfig
from collavn.errors import ConfigError
from collavn.models.config import ModelConfig
from collavn.training.config import (
    ImitationConfig,
    MapTrainConfig,
    PPOConfig,
    RunConfig,
    TrainConfig,
)


def _paper() -> TrainConfig:
    return TrainConfig(preset="paper")


def _cpu() -> TrainConfig:
    model = ModelConfig.cpu()
    return TrainConfig(
        preset="cpu",
        env=EnvConfig(panorama_width=128, panorama_height=32, goal_size=32,
                      difficulty="easy", render_threads=1),
        model=replace(model, map=replace(model.map, hidden=128), explore_prior=True),
        ppo=PPOConfig(rollout_steps=32, num_minibatches=2, update_epochs=4, lr=1e-3),
        mapping=MapTrainConfig(updates=2, batch_size=32, every=32, lr=3e-4),
        imitation=ImitationConfig(expert="seeker", dagger=True, buffer_rollouts=8, epochs=1),
        run=RunConfig(num_envs=8, checkpoint_interval=20))


#: The presets: name → (description, config).
PRESETS: dict[str, tuple[str, TrainConfig]] = {
    "paper": ("The paper's sizes and hyper-parameters (ResNet18, 512×128, 25 envs); "
              "for GPUs.", _paper()),
    "cpu": ("Sized to learn on a 2-core laptop CPU (small CNN, 128×32, 8 envs).", _cpu()),
}


def preset_config(name: str, **overrides: Any) -> TrainConfig:
    """The preset ``name`` with top-level fields replaced (``method=``, ``run=``, …)."""
    if name not in PRESETS:
        raise ConfigError(f"unknown preset {name!r}; expected one of {', '.join(PRESETS)}")
    return replace(PRESETS[name][1], **overrides)


#: Why the ``cpu`` preset departs from ``paper``: a dotted config path (a leaf, or a
#: section covering every leaf below it) → one line. :func:`preset_deviations` pairs
#: every differing field with its reason; a test fails if one has none.
CPU_REASONS: dict[str, str] = {
    "env.panorama_width": "3×32×128 panoramas: at 512×128 the encoder, not the renderer, "
                          "bounds CPU training (ResNet18 runs ~30 images/s on 2 cores)",
    "env.panorama_height": "see env.panorama_width",
    "env.goal_size": "32×32 goal images, to match the small panoramas",
    "env.difficulty": "easy episodes on the fly (the paper trains on its fixed mixed "
                      "dataset)",
    "env.render_threads": "one renderer thread: two runs can share the 2 cores",
    "model.panorama_shape": "derived from env.panorama_*",
    "model.goal_shape": "derived from env.goal_size",
    "model.encoder": "a small CNN instead of ResNet18 (forward+backward cost)",
    "model.embed_dim": "256-d embeddings (not 1024) for the small CNN",
    "model.hidden_size": "256-unit actor GRU (not 512): fewer parameters to learn on CPU",
    "model.critic_hidden_size": "128-unit critic GRU (not 512)",
    "model.critic_full_input": "the critic also sees the map and goal vectors; the paper's "
                               "V sees only (O, ω), which cannot tell how far the goal is",
    "model.odometry_input": "the last step's pose change is a direct policy input, so a "
                            "robot pushing against a wall can tell that it is not moving",
    "model.free_space_input": "16 free-space directions read off the depth panorama (the "
                              "explorer's sense, collavn.envs.free_space) join the map "
                              "vector; il on val40: 0.445 → 0.485 easy, 0.210 → 0.278 "
                              "medium SR",
    "model.goal_match": "goal matching (collavn.models.matching): the goal image compared "
                        "with the panorama at every azimuth and 3 scales, instead of a GRU "
                        "learning the comparison from two pooled embeddings",
    "model.readout": "the pretraining heads' predictions (sector distributions of the path "
                     "and goal bearings, distance, free space; collavn.models.readout) join "
                     "the goal vector, so 'turn towards the path' is linear in the input: "
                     "without them il's mean action learned almost no turning",
    "model.explore_prior": "the actor's means start from the goal-blind explorer's move (the "
                           "explore_action sensor) and learn what to add: an untrained "
                           "policy explores; il on val40 0.573 → 0.657 easy, 0.372 → 0.487 "
                           "medium SR (paired +0.085 [+0.035, +0.138], +0.115 [+0.058, "
                           "+0.170]), and 3.0 collision steps per easy agent-episode, not 11.9",
    "model.map.size": "a 96×96 map at 20 cm (19.2 m) instead of 384×384 at 10 cm",
    "model.map.resolution": "see model.map.size",
    "model.map.local_size": "32-cell local patches at 20 cm (6.4 m, as the paper's 64 at "
                            "10 cm)",
    "model.map.encoder_size": "the map encoder sees a 32×32 window",
    "model.map.feature_channels": "32 visual-feature channels (not 256) on the coarse grid",
    "model.map.feature_size": "a 6×6 feature grid over 19.2 m (3.2 m cells, the paper's "
                              "3 m grid)",
    "model.map.hidden": "256-unit predictor bottleneck (not 512)",
    "model.map.embed_dim": "128-d map vector (not 256)",
    "model.map.encoder_channels": "16/32/32 map-encoder channels (not 32/64/64): every PPO "
                                  "epoch runs it over every stored step; at 32/64/64 its "
                                  "convolutions were 43 % of a no-com update (profiled)",
    "model.comm.query_dim": "64-d queries and keys, 256-d values (not 256/256/2048), in "
                            "proportion to the 256-d embeddings",
    "model.comm.key_dim": "see model.comm.query_dim",
    "model.comm.value_dim": "see model.comm.query_dim",
    "run.num_envs": "8 envs (not 25) to fit 2 cores; they move on to the next 8 training "
                    "scenes at every checkpoint sync point",
    "run.checkpoint_interval": "20 updates between sync points (shorter rollouts)",
    "ppo.rollout_steps": "32-step rollouts (not 80): more updates per hour of CPU",
    "ppo.lr": "1e-3 (not 1e-5): 1e-5 (and 3e-4: approx-KL < 5e-4 per update) moves the "
              "policy too little in the ~1e5 agent-steps an hour gives",
    "ppo.update_epochs": "4 epochs × 2 mini-batches (not 8 × 5): the update dominates CPU "
                        "time",
    "ppo.num_minibatches": "see ppo.update_epochs",
    "mapping.updates": "2 map updates of batch 32 once per rollout (not 10 × 64 every env "
                       "step)",
    "mapping.batch_size": "see mapping.updates",
    "mapping.every": "see mapping.updates",
    "mapping.lr": "3e-4 (not 1e-4): far fewer map updates per hour",
    "imitation.dagger": "DAgger on (β = 0.95^update, ≥ 0.1) over the last 8 rollouts; the "
                        "paper's IL is plain BC",
    "imitation.buffer_rollouts": "see imitation.dagger",
    "imitation.epochs": "one pass over the aggregated rollouts per update",
    "imitation.expert": "il imitates the seeker (explorer until the goal is within 2 m in "
                        "straight view, then the oracle), not the oracle from the start: "
                        "on val40 0.448 → 0.598 easy, 0.280 → 0.400 medium SR (paired "
                        "+0.150 [+0.087, +0.210], +0.120 [+0.065, +0.177]); the learner "
                        "cannot tell where a farther goal is, and averaged the oracle's "
                        "turns into pushing on into walls",
}


def preset_deviations(a: str = "paper", b: str = "cpu",
                      reasons: dict[str, str] | None = None
                      ) -> dict[str, tuple[Any, Any, str | None]]:
    """``{path: (value in a, value in b, reason or None)}`` for every differing leaf.

    The reason is that of the longest key of ``reasons`` (default :data:`CPU_REASONS`)
    equal to the path or a dotted prefix of it.
    """
    reasons = CPU_REASONS if reasons is None else reasons
    diffs = configs.differences(PRESETS[a][1].to_dict(), PRESETS[b][1].to_dict())
    diffs.pop("preset", None)
    out: dict[str, tuple[Any, Any, str | None]] = {}
    for path, (va, vb) in diffs.items():
        keys = [k for k in reasons if path == k or path.startswith(k + ".")]
        out[path] = (va, vb, reasons[max(keys, key=len)] if keys else None)
    return out


#: The preset used when ``--preset`` is not given.
DEFAULT_PRESET = "cpu"


def parse_train_args(args: Sequence[str], prog: str = "collavn train") -> TrainConfig:
    """``[--preset NAME] [flags]`` → the config ``collavn train`` would run.

    The preset (default :data:`DEFAULT_PRESET`) supplies the defaults through tyro's
    overridable configs; every field is a flag.
    """
    return configs.parse_with_presets(
        PRESETS, args, prog, "Train a navigation agent (decentralized PPO or imitation)",
        DEFAULT_PRESET)
