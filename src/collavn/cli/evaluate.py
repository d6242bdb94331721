"""``collavn evaluate``: per-episode records and the paper's table for one policy."""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass

from collavn.errors import CollavnError
from collavn.evaluation.benchmark import (
    EvalConfig,
    load_dataset,
    run_evaluation,
    write_results,
)
from collavn.files import prepare_output_dir
from collavn.policies import check_mute


@dataclass(frozen=True)
class Evaluate(EvalConfig):
    """Score a policy on an episode dataset: per-episode records and the paper's table."""

    json: bool = False
    """Print the metrics as JSON instead of a table."""
    overwrite: bool = False
    """Replace the results in a non-empty ``--out``: the old directory is moved aside to
    ``OUT.old-<time>`` (without it a non-empty ``--out`` is refused)."""

    def run(self) -> int:
        """Check the output directory, evaluate, write files, print the table."""
        if self.mute:  # refused before the output directory is touched
            check_mute(self.policy)
        moved = prepare_output_dir(self.out, overwrite=self.overwrite)
        if moved is not None:
            print(f"moved the previous results in {self.out} to {moved}", file=sys.stderr)
        result = run_evaluation(self, load_dataset(self))
        if not result.records:
            raise CollavnError(f"no {self.difficulty} episodes in {self.dataset}")
        report = write_results(self.out, {self.policy: result})
        print(json.dumps(report.to_json(), indent=2) if self.json else report.to_markdown())
        return 0
