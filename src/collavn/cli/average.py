"""``collavn average``: one policy from the mean weights of a run's checkpoints."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from collavn.policies.checkpoint import save_checkpoint
from collavn.training.checkpoint import average_checkpoints


@dataclass
class Average:
    """Average the weights of checkpoints of one run into one policy checkpoint.

    Stochastic weight averaging over a run's snapshots (``collavn train
    --snapshot-every N`` keeps them in ``OUT/snapshots/``), e.g. those of its second
    half; evaluate the result with ``collavn evaluate --policy OUT``. The checkpoints
    must come from one configuration.
    """

    checkpoints: Annotated[tuple[Path, ...], tyro.conf.Positional]
    """Checkpoint files of one run (at least two)."""
    out: Path
    """The averaged checkpoint to write (atomically)."""

    def run(self) -> int:
        """Load, check, average, write, and say what went in."""
        payload = average_checkpoints(self.checkpoints)
        path = save_checkpoint(self.out, payload)
        steps = ", ".join(f"{s['agent_steps']:,}" for s in payload["averaged_from"])
        print(f"averaged {len(self.checkpoints)} checkpoints (agent-steps {steps}) → {path}")
        return 0
