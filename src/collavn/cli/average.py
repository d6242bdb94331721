"""``collavn average``: one policy from the mean weights of a run's checkpoints."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from collavn.errors import ConfigError
from collavn.policies.checkpoint import save_checkpoint
from collavn.training.checkpoint import average_checkpoints, run_snapshots


@dataclass
class Average:
    """Average the weights of checkpoints of one run into one policy checkpoint.

    Stochastic weight averaging over a run's snapshots (``collavn train
    --snapshot-every N`` keeps them in ``RUN/snapshots/``): ``collavn average RUN --out
    F`` takes those of the run's second half; evaluate the result with ``collavn
    evaluate --policy F``. The checkpoints must come from one configuration.
    """

    checkpoints: Annotated[tuple[Path, ...], tyro.conf.Positional]
    """Checkpoint files of one run (at least two), or a run directory: its snapshots."""
    out: Path
    """The averaged checkpoint to write (atomically)."""
    from_steps: int | None = None
    """For a run directory: its snapshots from this many agent-steps on (default: the
    second half, from half the last snapshot's agent-steps)."""

    def paths(self) -> list[Path]:
        """The checkpoint files to average: files as given, directories expanded."""
        if self.from_steps is not None and not any(p.is_dir() for p in self.checkpoints):
            raise ConfigError("--from-steps picks a run directory's snapshots; give a run "
                              "directory (or leave it out)")
        return [q for p in self.checkpoints
                for q in (run_snapshots(p, self.from_steps) if p.is_dir() else [p])]

    def run(self) -> int:
        """Load, check, average, write, and say what went in."""
        paths = self.paths()
        payload = average_checkpoints(paths)
        path = save_checkpoint(self.out, payload)
        steps = ", ".join(f"{s['agent_steps']:,}" for s in payload["averaged_from"])
        print(f"averaged {len(paths)} checkpoints (agent-steps {steps}) → {path}")
        return 0
