"""``collavn evaluate``: per-episode records and the paper's table for one policy."""

from __future__ import annotations

import json
from dataclasses import dataclass

from collavn.errors import CollavnError
from collavn.evaluation.benchmark import (
    EvalConfig,
    load_dataset,
    run_evaluation,
    summary_json,
    write_results,
)


@dataclass(frozen=True)
class Evaluate(EvalConfig):
    """Score a policy on an episode dataset: per-episode records and the paper's table."""

    json: bool = False
    """Print the metrics as JSON instead of a table."""

    def run(self) -> int:
        """Evaluate, write files, print the table."""
        records, trajectories = run_evaluation(self, load_dataset(self))
        if not records:
            raise CollavnError(f"no {self.difficulty} episodes in {self.dataset}")
        table = write_results(self.out, {self.policy: records}, trajectories)
        print(json.dumps(summary_json(table), indent=2) if self.json else table.to_markdown())
        return 0
