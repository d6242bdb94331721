r"""``collavn pretrain``: learn the frame perception from simulator labels, once.

Example::

    collavn pretrain --preset cpu --out runs/enc --time-budget-minutes 20
    collavn train --preset cpu --method il --encoder runs/enc/encoder.pt --out runs/il

The preset (default ``cpu``; ``paper`` pretrains the ResNet18 encoder at 512×128) takes
``env`` and ``model`` from the ``train`` preset of the same name, so the encoder fits
``collavn train --preset NAME``. Every field of
:class:`~collavn.perception.config.PretrainConfig` is a flag.
"""

from __future__ import annotations

import signal
from collections.abc import Sequence

from collavn.configs import parse_with_presets
from collavn.perception.config import PerceptionConfig, PretrainConfig
from collavn.training.presets import PRESETS

DEFAULT_PRESET = "cpu"


def pretrain_presets() -> dict[str, tuple[str, PretrainConfig]]:
    """``name → (description, config)`` from the train presets' env and model."""
    paper = PerceptionConfig(train_scenes=25, frames_per_scene=64, goals_per_scene=8,
                             val_frames_per_scene=32, batch_size=32, lr=3e-4)
    sizes = {"cpu": PerceptionConfig(), "paper": paper}
    return {name: (f"{doc} Pretraining its frame perception.",
                   PretrainConfig(preset=name, env=cfg.env, model=cfg.model,  # type: ignore[arg-type]
                                  perception=sizes[name]))
            for name, (doc, cfg) in PRESETS.items()}


def parse(args: Sequence[str], prog: str = "collavn pretrain") -> PretrainConfig:
    """``[--preset NAME] [flags]`` → the resolved :class:`PretrainConfig`."""
    return parse_with_presets(pretrain_presets(), args, prog,
                              "Pretrain the frame perception on simulator labels",
                              DEFAULT_PRESET)


def main(args: Sequence[str], prog: str = "collavn pretrain") -> int:
    """Parse, pretrain, print the held-out accuracies and where the encoder went.

    SIGINT or SIGTERM ends the run after the current step with the encoder written
    (exit ``128 + signal``); a second signal stops at once without writing.
    """
    config = parse(args, prog)
    from pathlib import Path

    from collavn.perception.pretrain import ENCODER_FILE, pretrain
    from collavn.training.interrupt import StopRequest

    encoder = Path(config.out) / ENCODER_FILE
    notice = f"finishing the current step, then scoring the held-out frames and writing {encoder}"
    with StopRequest(encoder, 1, notice) as stop:
        result = pretrain(config, lambda: stop.requested)
    from collavn.perception.pretrain import ACCURACY_BANDS

    def band(key: str) -> str:
        return next((b for b in ACCURACY_BANDS if key.endswith(f"_{b}")), "")

    shown = ", ".join(f"{k.removeprefix('val/')} {v:.3f}" for k, v in result.metrics.items()
                      if not band(k))
    print(f"{result.steps} steps; held out: {shown}; encoder {result.path}")
    for b, (lo, hi) in ACCURACY_BANDS.items():  # the pair labels per distance band
        parts = [f"{k.removeprefix('val/').removesuffix(f'_accuracy_{b}')} {v:.3f}"
                 for k, v in result.metrics.items() if band(k) == b]
        if parts:
            print(f"  goal {lo:g}–{hi:g} m away ({b}): {', '.join(parts)}")
    if stop.signum is None:
        return 0
    print(f"stopped by {signal.Signals(stop.signum).name} after {result.steps} steps; "
          f"the encoder above holds them")
    return 128 + stop.signum
