"""Supervised training of the map module F_map alongside the policy.

Every env step pushes each active agent's (panorama, depth, ground-truth local map) into
a FIFO of ``fifo_size`` samples; every ``every`` steps the local-map predictor takes
``updates`` Adam steps on random batches of ``batch_size`` from it (paper: 5,000
samples, 10 updates of batch 64 per step). Only the local-map predictor's weights are
trained here; the policy optimizer never touches them. The map builder's visual-feature
projection (``feature_proj``) has no supervised target: it is a policy parameter.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import cast

import numpy as np
import torch
from torch import Tensor, nn

from collavn.models.mapping import map_loss
from collavn.models.optim import adam
from collavn.models.policy import ActorCritic, AgentTower
from collavn.training.config import MapTrainConfig


def map_parameters(model: ActorCritic) -> Iterator[nn.Parameter]:
    """The weights of every tower's local-map predictor (trained by :func:`map_loss`)."""
    for tower in model.towers:
        yield from cast(AgentTower, tower).map_builder.predictor.parameters()


def policy_parameters(model: ActorCritic) -> list[nn.Parameter]:
    """Every weight the policy loss trains.

    Not the map predictors' (those learn from :class:`MapTrainer`), not a frozen encoder's.
    """
    mapped = {id(p) for p in map_parameters(model)}
    return [p for p in model.parameters() if id(p) not in mapped and p.requires_grad]


class MapFIFO:
    """A ring buffer of ``(panorama, depth, gt_map)`` samples, oldest overwritten first."""

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self.data: dict[str, np.ndarray] = {}
        self.size = 0
        self.cursor = 0

    def clear(self) -> None:
        """Forget every sample."""
        self.size, self.cursor = 0, 0

    def push(self, samples: Mapping[str, np.ndarray]) -> None:
        """Append ``B`` samples (every entry ``(B, ...)``)."""
        count = len(next(iter(samples.values())))
        if not self.data:
            self.data = {k: np.zeros((self.capacity, *v.shape[1:]), v.dtype)
                         for k, v in samples.items()}
        first = max(0, count - self.capacity)  # of more than fit, only the last ones stay
        slots = (self.cursor + np.arange(first, count)) % self.capacity
        for k, v in samples.items():
            self.data[k][slots] = v[first:]
        self.cursor = (self.cursor + count) % self.capacity
        self.size = min(self.size + count, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, np.ndarray]:
        """``batch_size`` samples drawn uniformly with replacement."""
        index = rng.integers(0, self.size, batch_size)
        return {k: v[index] for k, v in self.data.items()}


class MapTrainer:
    """Owns the FIFO and the map optimizer.

    Call :meth:`observe` once per env step during collection: it only stores samples and
    counts the updates owed (``cfg.updates`` every ``cfg.every`` steps). Call
    :meth:`train_owed` after the policy update: the map weights never change while a
    rollout is collected or re-scored, so PPO scores a rollout with the model that
    collected it (the first epoch's ratio is exactly 1).

    Args:
        model: The actor-critic whose map builders are trained.
        cfg: FIFO and update settings.
        use_depth: The predictor also reads depth.
        seed: Seeds the batch sampling.
        sync_gradients: Averages gradients over processes (distributed runs).
    """

    def __init__(self, model: ActorCritic, cfg: MapTrainConfig, use_depth: bool, seed: int,
                 sync_gradients: Callable[[list[nn.Parameter]], None] | None = None) -> None:
        self.model, self.cfg, self.use_depth = model, cfg, use_depth
        self.params = list(map_parameters(model))
        self.optimizer = adam(self.params, lr=cfg.lr)
        self.fifo = MapFIFO(cfg.fifo_size)
        self.rng = np.random.default_rng(seed)
        self.sync_gradients = sync_gradients
        self.steps = 0
        self.owed = 0
        self.last_loss = float("nan")

    def reseed(self, seed: int) -> None:
        """Empty the FIFO and restart the sampler (checkpoint sync points)."""
        self.fifo.clear()
        self.rng = np.random.default_rng(seed)
        self.steps = 0
        self.owed = 0

    def observe(self, obs: Mapping[str, np.ndarray]) -> None:
        """Push the active agents' samples; owe ``cfg.updates`` every ``cfg.every`` calls."""
        if not self.cfg.enabled:
            return
        active = obs["active"]
        keys = ("panorama", "gt_map", "depth") if self.use_depth else ("panorama", "gt_map")
        self.fifo.push({k: obs[k][active] for k in keys})
        self.steps += 1
        if self.steps % self.cfg.every == 0:
            self.owed += self.cfg.updates

    def train_owed(self) -> None:
        """Run the updates owed since the last call (after the policy update)."""
        if self.owed and self.fifo.size > 0:
            self.last_loss = self.train(self.owed)
        self.owed = 0

    def train(self, updates: int) -> float:
        """``updates`` gradient steps; returns the mean loss."""
        losses = []
        device = self.model.device
        for _ in range(updates):
            batch = {k: torch.as_tensor(v).to(device)
                     for k, v in self.fifo.sample(self.cfg.batch_size, self.rng).items()}
            loss = self.loss(batch)
            self.optimizer.zero_grad(set_to_none=False)
            loss.backward()
            if self.sync_gradients is not None:
                self.sync_gradients(self.params)
            self.optimizer.step()
            losses.append(float(loss.detach()))
        return float(np.mean(losses))

    def loss(self, batch: Mapping[str, Tensor]) -> Tensor:
        """Map loss of the first tower's predictor on a batch (shared weights)."""
        predictor = cast(AgentTower, self.model.towers[0]).map_builder.predictor
        logits, _ = predictor(batch["panorama"], batch.get("depth"))
        return map_loss(logits, batch["gt_map"])
