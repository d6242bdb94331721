"""``collavn experiment``: the paper's table end to end, resumable, with a report."""

from __future__ import annotations

from dataclasses import dataclass

from collavn.experiments import ExperimentConfig, run_experiment, write_report


@dataclass(frozen=True)
class Experiment(ExperimentConfig):
    """Datasets, training of il / no-com / no-mem / ours, evaluation of them and of random,
    explorer and oracle, comparisons, Ad-hoCoop, and ``OUT/report.md``; run again with
    the same arguments to resume.
    """

    def run(self) -> int:
        """Run or resume every stage; print where the report is."""
        print(f"report: {run_experiment(self, write_report)}")
        return 0
