"""Experiments: the paper's table end to end for a compute budget (``collavn experiment``)."""

from collavn.experiments.pipeline import ExperimentConfig, run_experiment
from collavn.experiments.report import write_report

__all__ = ["ExperimentConfig", "run_experiment", "write_report"]
