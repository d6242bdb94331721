"""A tiny training configuration: seconds per update on one CPU thread."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

from collavn.envs.config import EnvConfig
from collavn.models.config import CommConfig, MapConfig, ModelConfig, ReadoutConfig
from collavn.training.config import MapTrainConfig, PPOConfig, RunConfig, TrainConfig
from collavn.training.presets import preset_config

TINY_MODEL = ModelConfig.cpu(
    embed_dim=32, hidden_size=32, critic_hidden_size=16,
    map=MapConfig(size=32, resolution=0.2, local_size=16, feature_channels=4,
                  feature_size=4, hidden=32, encoder_size=16, embed_dim=16),
    comm=CommConfig(query_dim=8, key_dim=8, value_dim=16, memory_slots=8),
    readout=ReadoutConfig(enabled=True, bins=8, hidden=32))


def tiny_config(method: str = "ours", out: str = "runs/tiny", rollout_steps: int = 4,
                **overrides: Any) -> TrainConfig:
    """Two envs of two agents in one procedural scene, 32×64 panoramas, tiny nets."""
    base = preset_config(
        "cpu", method=method, model=TINY_MODEL,
        env=EnvConfig(panorama_width=64, panorama_height=16, goal_size=16,
                      difficulty="easy", render_threads=1),
        run=RunConfig(out=out, num_envs=2, scenes=("procedural:0",), checkpoint_interval=2,
                      progress=False, torch_threads=1),
        mapping=MapTrainConfig(fifo_size=64, updates=1, batch_size=8, every=2),
        ppo=PPOConfig(rollout_steps=rollout_steps, num_minibatches=2, update_epochs=2,
                      lr=3e-4))
    return replace(base, **overrides)
