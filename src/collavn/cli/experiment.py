"""``collavn experiment``: the paper's table end to end, resumable, with a report."""

from __future__ import annotations

from dataclasses import dataclass

from collavn.experiments import ExperimentConfig, run_experiment, write_report


@dataclass(frozen=True)
class Experiment(ExperimentConfig):
    """The paper's table end to end: datasets, training, evaluation, report.

    Trains il / no-com / no-mem / ours within the budget, evaluates them and random,
    explorer and oracle on the test split, compares them, runs Ad-hoCoop, and writes
    ``OUT/report.md``. Run again with the same arguments to resume.
    """

    def run(self) -> int:
        """Run or resume every stage; print where the report is."""
        print(f"report: {run_experiment(self, write_report)}")
        return 0
