"""``collavn evaluate``: per-episode records and the paper's table for one policy."""

from __future__ import annotations

import json
from dataclasses import dataclass

from collavn.errors import CollavnError
from collavn.evaluation.benchmark import (
    EvalConfig,
    load_dataset,
    run_evaluation,
    write_results,
)


@dataclass(frozen=True)
class Evaluate(EvalConfig):
    """Score a policy on an episode dataset: per-episode records and the paper's table."""

    json: bool = False
    """Print the metrics as JSON instead of a table."""

    def run(self) -> int:
        """Evaluate, write files, print the table."""
        result = run_evaluation(self, load_dataset(self))
        if not result.records:
            raise CollavnError(f"no {self.difficulty} episodes in {self.dataset}")
        report = write_results(self.out, {self.policy: result})
        print(json.dumps(report.to_json(), indent=2) if self.json else report.to_markdown())
        return 0
