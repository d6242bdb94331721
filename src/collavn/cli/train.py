r"""``collavn train``: pick a method and a preset, override any field, train.

Example::

    collavn train --method ours --task commongoal --agents 2 --preset cpu --out runs/ours
    collavn train --preset cpu --method no-com --ppo.lr 1e-4 --ppo.critic-warmup 10 \\
        --init-from runs/il/checkpoint.pt --out runs/ft
    torchrun --nproc-per-node 2 -m collavn.cli train --method no-com --preset cpu --out x

Every field of :class:`~collavn.training.config.TrainConfig` is a flag (``--ppo.clip-coef
0.1``, ``--model.hidden-size 128``, ``--env.camera-height 1.2``); the preset (default
``cpu``) supplies the defaults through tyro's overridable configs. The resolved
configuration is written to ``OUT/config.json`` and into every checkpoint.

A non-empty ``--out`` is refused unless ``--resume`` (continue its checkpoint) or
``--overwrite`` (move it aside to ``OUT.old-<time>`` and start over); ``--resume-from
RUN/checkpoint.pt`` continues another run's checkpoint in a new ``--out`` (to extend a
finished run and keep it). Ctrl-C or SIGTERM
stops at the next checkpoint sync point with a checkpoint and prints how to resume
(exit 130 / 143); a second one stops at once without saving.
"""

from __future__ import annotations

import shlex
import signal
import sys
from collections.abc import Sequence

from collavn.training.config import TrainConfig
from collavn.training.presets import parse_train_args


def parse(args: Sequence[str], prog: str = "collavn train") -> TrainConfig:
    """``[--preset NAME] [flags]`` → the resolved :class:`TrainConfig`."""
    return parse_train_args(args, prog)


def main(args: Sequence[str], prog: str = "collavn train") -> int:
    """Parse, train, print where the checkpoint went."""
    config = parse(args, prog)
    from collavn.training.trainer import train

    result = train(config)
    if result.moved is not None:
        print(f"moved the previous run in {config.run.out} to {result.moved}")
    if result.checkpoint is not None:
        sr = result.last.get("episode/success_rate", float("nan"))
        print(f"{result.iterations} updates, {result.agent_steps} agent-steps, "
              f"training SR {sr:.3f}; checkpoint {result.checkpoint}")
    if result.signal is None:
        return 0
    print(f"collavn: stopped by {signal.Signals(result.signal).name} after update "
          f"{result.iterations}; checkpoint {result.checkpoint}. Continue with:\n  "
          f"{prog} {shlex.join(resume_args(args))}", file=sys.stderr)
    return 128 + result.signal


def resume_args(args: Sequence[str]) -> list[str]:
    """``args`` made to continue the run in its ``--out``.

    ``--resume`` replaces ``--overwrite`` and ``--resume-from FILE`` (the run's
    checkpoint is ``OUT``'s now).
    """
    out: list[str] = []
    skip = False
    for a in args:
        if skip:
            skip = False
        elif a == "--resume-from":
            skip = True
        elif a not in ("--resume", "--overwrite") and not a.startswith("--resume-from="):
            out.append(a)
    return out + ["--resume"]
