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

from collections.abc import Sequence

import tyro

from collavn.perception.config import PerceptionConfig, PretrainConfig
from collavn.training.presets import PRESETS

DEFAULT_PRESET = "cpu"


def pretrain_presets() -> dict[str, tuple[str, PretrainConfig]]:
    """``name → (description, config)`` from the train presets' env and model."""
    paper = PerceptionConfig(frames_per_scene=64, goals_per_scene=8,
                             val_frames_per_scene=32, batch_size=32, lr=3e-4)
    sizes = {"cpu": PerceptionConfig(), "paper": paper}
    return {name: (f"{doc} Pretraining its frame perception.",
                   PretrainConfig(preset=name, env=cfg.env, model=cfg.model,  # type: ignore[arg-type]
                                  perception=sizes[name]))
            for name, (doc, cfg) in PRESETS.items()}


def parse(args: Sequence[str], prog: str = "collavn pretrain") -> PretrainConfig:
    """``[--preset NAME] [flags]`` → the resolved :class:`PretrainConfig`."""
    args = list(args)
    presets = pretrain_presets()
    preset = DEFAULT_PRESET
    for i, a in enumerate(args):
        if a == "--preset" and i + 1 < len(args):
            preset = args[i + 1]
            del args[i:i + 2]
            break
        if a.startswith("--preset="):
            preset = a.split("=", 1)[1]
            del args[i]
            break
    if preset not in presets:
        raise SystemExit(f"{prog}: error: unknown preset {preset!r}; expected one of "
                         f"{', '.join(presets)}")
    description = (f"Pretrain the frame perception on simulator labels; preset {preset!r}: "
                   f"{presets[preset][0]} Choose with --preset {{{','.join(presets)}}} "
                   f"(default {DEFAULT_PRESET}).")
    return tyro.extras.overridable_config_cli(
        {preset: (description, presets[preset][1])}, args=[preset, *args], prog=prog,
        description=description)


def main(args: Sequence[str], prog: str = "collavn pretrain") -> int:
    """Parse, pretrain, print the held-out accuracies and where the encoder went."""
    config = parse(args, prog)
    from collavn.perception.pretrain import pretrain

    result = pretrain(config)
    shown = ", ".join(f"{k.removeprefix('val/')} {v:.3f}" for k, v in result.metrics.items())
    print(f"{result.steps} steps; held out: {shown}; encoder {result.path}")
    return 0
