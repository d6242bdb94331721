"""Supervised pretraining of the frame perception on simulator labels (``collavn pretrain``).

Why these labels (:mod:`collavn.perception.labels`): a navigation policy needs, every
step, (1) which way the shortest path to the goal leaves the agent — the label that turns
imitation into reading one number, and that the goal image alone must reveal (goal
matching makes it easy when the goal's surfaces are in view, the panorama's layout when
they are not); (2) how far the goal still is (geodesic, not straight-line: round corners
the straight line lies); (3) the straight-line bearing of the goal, which ties the goal
image's content to a direction in the panorama; (4) how far the robot can drive in every
direction — the label whose absence makes learned agents push into walls. Relative pose
between two views is left out: odometry is an input and the map integrates it.

The loop: render and label the frames once (train and val scenes), then
``steps`` Adam steps on random pairs with exact rotation/mirror augmentation; TensorBoard
scalars, held-out accuracy per label every ``eval_interval`` steps, and ``encoder.pt``
written atomically at the end (also when the time budget runs out). With
``perception.ema`` an exponential moving average of the weights is what is scored and
saved.
"""

from __future__ import annotations

import copy
import json
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import torch
from torch import nn

from collavn.datasets.episode import DIFFICULTY_BINS, in_bin
from collavn.metrics import SIGHT_DISTANCE
from collavn.models.frames import FramePerception
from collavn.models.optim import adam
from collavn.models.readout import PerceptionReadout
from collavn.perception.config import PerceptionConfig, PretrainConfig
from collavn.perception.encoder import encoder_spec, save_encoder
from collavn.perception.frames import FrameSet, render_frames, sample_batch
from collavn.perception.heads import LABELS, accuracies, losses, pair_hits, targets
from collavn.scenes import load_scene
from collavn.scenes.splits import scene_specs
from collavn.threads import apply_threads

#: Geodesic distance bands ``[lo, hi)`` (metres) of the per-band held-out accuracy: each
#: episode difficulty's bin, and ``homing`` — from the success radius (1 m) to the
#: distance at which an agent has its goal in sight (:data:`~collavn.metrics.SIGHT_DISTANCE`):
#: where an agent that sees its goal must head for it, and where the ``il`` expert
#: switches to the shortest path. Measured (the 2026-12-05 weight-averaged ``cpu``
#: encoder): path direction right on 0.43 of held-out pairs there, 0.66 at 3–5 m. The
#: evaluation's homing rate (``collavn evaluate``: SR once the goal was sighted) is where
#: that shows: 0.75 for the ``il`` trained on it, 0.99 for its expert.
ACCURACY_BANDS: dict[str, tuple[float, float]] = {"homing": (1.0, SIGHT_DISTANCE),
                                                  **DIFFICULTY_BINS}


def _in_band(distance: np.ndarray, band: str) -> np.ndarray:
    if band in DIFFICULTY_BINS:
        return in_bin(distance, band)
    lo, hi = ACCURACY_BANDS[band]
    return (distance >= lo) & (distance < hi)

ENCODER_FILE = "encoder.pt"
#: The labels of a (panorama, goal) pair, scored per episode difficulty too.
PAIR_LABELS = ("path_bearing", "goal_bearing", "distance")


@dataclass(frozen=True)
class PretrainResult:
    """What :func:`pretrain` returns: steps done, last held-out metrics, the file."""

    steps: int
    metrics: dict[str, float]
    path: Path


class WeightAverage:
    """An exponential moving average of a module's floating-point state, bias-corrected.

    After ``n`` updates with decay ``d`` every entry is ``Σ_i (1 − d) d^(n−i) w_i / (1 −
    d^n)``: the weights of the last ~1/(1 − d) steps, with no pull towards the
    initialisation (a short run is averaged over its own steps). Integer buffers are
    copied. :meth:`module` is a copy of the module holding the average.
    """

    def __init__(self, module: nn.Module, decay: float) -> None:
        self.decay, self.updates = decay, 0
        self.copy = copy.deepcopy(module)
        state = module.state_dict()
        self.sums = {k: torch.zeros_like(v) for k, v in state.items() if v.is_floating_point()}
        self.others = {k: v.clone() for k, v in state.items() if k not in self.sums}

    @torch.no_grad()
    def update(self, module: nn.Module) -> None:
        """Fold in the module's current state."""
        self.updates += 1
        for k, v in module.state_dict().items():
            if k in self.sums:
                self.sums[k].lerp_(v, 1.0 - self.decay)
            else:
                self.others[k].copy_(v)

    @torch.no_grad()
    def module(self) -> nn.Module:
        """The copy, loaded with the average (the trained state before any update)."""
        if self.updates:
            scale = 1.0 / (1.0 - self.decay ** self.updates)
            self.copy.load_state_dict({**self.others,
                                       **{k: v * scale for k, v in self.sums.items()}})
        return self.copy


class Pretrainer:
    """The frame perception, its heads and optimizer, over a train and a val frame set."""

    def __init__(self, cfg: PretrainConfig, train: FrameSet, val: FrameSet) -> None:
        self.cfg, self.train, self.val = cfg, train, val
        torch.manual_seed(cfg.seed)
        self.frames = FramePerception(cfg.model)
        p = cfg.perception
        # The model's own readout if it has one (its parameters are the frames', saved
        # with the encoder), else heads of their own that are discarded after.
        own = self.frames.readout
        self.heads = own or PerceptionReadout(self.frames.embed_size,
                                              self.frames.pair_goal_size, p.bins, p.hidden)
        params = [*self.frames.parameters(), *([] if own else self.heads.parameters())]
        self.optimizer = adam(params, lr=p.lr)
        self.rng = np.random.default_rng(cfg.seed + 1)
        # (A readout of the model's own is both entries: copies keep it one module.)
        self.net = nn.ModuleDict({"frames": self.frames, "heads": self.heads})
        self.average = WeightAverage(self.net, p.ema) if p.ema > 0 else None

    def modules_for(self, averaged: bool = True) -> tuple[FramePerception, nn.Module]:
        """The frame perception and heads to score and save.

        The weight average's when ``perception.ema`` is on and ``averaged``, else the
        trained weights.
        """
        net = self.average.module() if averaged and self.average is not None else self.net
        assert isinstance(net, nn.ModuleDict)
        frames, heads = net["frames"], net["heads"]
        assert isinstance(frames, FramePerception)
        return frames, heads

    def loss(self, batch: dict[str, np.ndarray]) -> tuple[torch.Tensor, dict[str, float]]:
        """Total loss of a batch and its parts."""
        p = self.cfg.perception
        t = {k: torch.as_tensor(v) for k, v in batch.items()}
        parts = losses(self.heads(*self.frames.see_pair(t["panorama"], t["goal"], t.get("depth"))),
                       targets(t, p.bins, p.max_distance))
        total = torch.stack(list(parts.values())).sum()
        return total, {k: float(v.detach()) for k, v in parts.items()}

    def step(self) -> dict[str, float]:
        """One Adam step on a fresh augmented batch; returns the losses."""
        self.net.train()
        batch = sample_batch(self.train, self.cfg.perception.batch_size, self.cfg.perception,
                             self.rng)
        total, parts = self.loss(batch)
        self.optimizer.zero_grad()
        total.backward()
        self.optimizer.step()
        if self.average is not None:
            self.average.update(self.net)
        return {"loss/total": float(total.detach()), **{f"loss/{k}": v
                                                         for k, v in parts.items()}}

    @torch.no_grad()
    def evaluate(self, pairs: int = 4096, averaged: bool = True,
                 prefix: str = "val") -> dict[str, float]:
        """Held-out accuracy and loss per label on ``pairs`` val pairs.

        The pairs are a fixed draw with :func:`held_out_config`'s settings. The pair
        labels are also scored per band of :data:`ACCURACY_BANDS` — the pairs whose
        geodesic distance lies in an episode difficulty's bin
        (``val/path_bearing_accuracy_easy``, …) or in the homing band
        (``…_accuracy_homing``): a perception that is right far from the goal (where the
        way out of the room is the answer) can still be wrong at the distances an episode
        is decided. ``averaged``: score the weight average (``perception.ema``) rather
        than the trained weights; ``prefix`` names the scalars.
        """
        frames, heads = self.modules_for(averaged)
        frames.eval()
        heads.eval()
        p = held_out_config(self.cfg.perception)
        rng = np.random.default_rng(12345)
        right: dict[str, list[float]] = {k: [] for k in LABELS}
        bands = {b: {k: [0, 0] for k in PAIR_LABELS} for b in ACCURACY_BANDS}
        loss = []
        for _ in range(max(1, pairs // p.batch_size)):
            batch = sample_batch(self.val, p.batch_size, p, rng, augment=False)
            t = {k: torch.as_tensor(v) for k, v in batch.items()}
            pred = heads(*frames.see_pair(t["panorama"], t["goal"], t.get("depth")))
            target = targets(t, p.bins, p.max_distance)
            loss.append(float(torch.stack(list(losses(pred, target).values())).sum()))
            for k, v in accuracies(pred, target).items():
                right[k].append(float(v))
            hits = pair_hits(pred, target)
            for band, counts in bands.items():
                mask = target["reachable"] & torch.as_tensor(_in_band(batch["distance"], band))
                n = int(mask.sum())
                for k, c in counts.items():
                    c[0] += int(hits[k][mask].sum())
                    c[1] += n
        return {f"{prefix}/loss": float(np.mean(loss)),
                **{f"{prefix}/{k}_accuracy": float(np.nanmean(v)) for k, v in right.items()},
                **{f"{prefix}/{k}_accuracy_{band}": hit / n for band, counts in bands.items()
                   for k, (hit, n) in counts.items() if n}}


def held_out_config(p: PerceptionConfig) -> PerceptionConfig:
    """``p`` with the held-out draw's settings.

    Those are the defaults of ``near_distance`` and ``own_goal_fraction``, whatever the
    training draw uses. The held-out frames and pairs are the ruler every encoder is
    scored with: a run that trains nearer its goals (``--perception.near-distance 5``)
    must be scored on the same kind of pairs as one that does not, or its accuracies
    are not comparable.
    """
    return replace(p, near_distance=PerceptionConfig.near_distance,
                   own_goal_fraction=PerceptionConfig.own_goal_fraction)


def load_frames(cfg: PretrainConfig, progress: object) -> tuple[FrameSet, FrameSet]:
    """Render and label the train and val frame sets.

    Each set has its own random stream from ``cfg.seed``, and the val set is drawn with
    :func:`held_out_config`: the held-out frames do not change with the training draw's
    settings (how many training scenes, how near the goals).
    """
    from rich.progress import Progress, TaskID

    assert isinstance(progress, Progress)
    p = cfg.perception
    train_specs = scene_specs("train", (p.train_scenes, 0, 0))
    out: list[FrameSet] = []
    for specs, count, name, draw in ((cfg.scenes or tuple(train_specs),
                                      p.frames_per_scene, "train", p),
                                     (cfg.val_scenes or tuple(scene_specs("val")),
                                      p.val_frames_per_scene, "val", held_out_config(p))):
        task = progress.add_task(f"rendering {name} frames", total=len(specs))
        scenes = [load_scene(s) for s in specs]

        def advance(k: int, task: TaskID = task) -> None:
            progress.advance(task, k)

        rng = np.random.default_rng([cfg.seed, len(out)])
        out.append(render_frames(scenes, cfg.env, draw, count, rng, advance,
                                 depth=cfg.model.frame_depth))
    return out[0], out[1]


def pretrain(cfg: PretrainConfig, stop: Callable[[], bool] | None = None) -> PretrainResult:
    """Pretrain the frame perception; writes ``OUT/encoder.pt``.

    ``stop`` is asked after every step (``collavn pretrain`` passes "a SIGINT or SIGTERM
    arrived"); once it answers true the run scores the held-out frames, writes the
    encoder with the steps done and returns.
    """
    from rich.progress import Progress
    from torch.utils.tensorboard import SummaryWriter

    apply_threads(cfg.torch_threads)
    started = time.perf_counter()
    out = Path(cfg.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2) + "\n")
    writer = SummaryWriter(str(out))
    budget = 60.0 * cfg.time_budget_minutes
    with Progress(disable=not cfg.progress) as progress:
        train, val = load_frames(cfg, progress)
        trainer = Pretrainer(cfg, train, val)
        task = progress.add_task("pretraining", total=cfg.perception.steps)
        metrics: dict[str, float] = {}
        step = 0
        while step < cfg.perception.steps:
            scalars = trainer.step()
            step += 1
            over = ((budget > 0 and time.perf_counter() - started >= budget)
                    or (stop is not None and stop()))
            if step % cfg.eval_interval == 0 or step == cfg.perception.steps or over:
                metrics = trainer.evaluate()
                scalars.update(metrics)
                if trainer.average is not None:  # the raw weights, for comparison
                    scalars.update(trainer.evaluate(averaged=False, prefix="val_raw"))
            if step % cfg.log_interval == 0 or "val/loss" in scalars:
                for k, v in scalars.items():
                    writer.add_scalar(k, v, step)
            progress.update(task, completed=step, description=(
                f"pretraining loss {scalars['loss/total']:.3f}"
                + (f" path acc {metrics['val/path_bearing_accuracy']:.2f}" if metrics
                   else "")))
            if over:
                break
    writer.close()
    path = save_encoder(out / ENCODER_FILE, trainer.modules_for()[0],
                        encoder_spec(cfg.model, cfg.env.camera_height), metrics,
                        cfg.to_dict(), step)
    return PretrainResult(step, metrics, path)
