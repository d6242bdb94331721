"""``collavn compare``: paired bootstrap differences between evaluations of one dataset."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import tyro

from collavn.errors import CollavnError
from collavn.evaluation.compare import (
    compare_recipes,
    compare_records,
    comparisons_to_markdown,
)
from collavn.evaluation.runner import read_records
from collavn.metrics import AgentRecord


@dataclass
class Compare:
    """Compare evaluations of the same episodes (paired bootstrap over episodes).

    SR, SPL and DTS differences with 95 % intervals, per difficulty and overall. Every
    evaluation after the first is compared with the first (Δ = it − first); with
    ``--pool``, their mean is (runs of one recipe, e.g. training seeds). Two recipes over
    seeds: ``--pool --baseline-runs K`` pools the first K as the baseline.
    """

    evaluations: Annotated[tuple[Path, ...], tyro.conf.Positional]
    """Evaluation output directories (holding ``records.jsonl``) or records files;
    the first is the baseline (the first K with ``--baseline-runs K``)."""
    samples: int = 5000
    """Bootstrap resamples of the episodes."""
    seed: int = 0
    """Seeds the resampling."""
    pool: bool = False
    """Compare the mean of the evaluations after the first (runs of one recipe: seeds)
    with the first, in one row. The interval resamples the runs as well as the
    episodes, so it holds the spread between seeds too (roughly, with few runs)."""
    baseline_runs: int = 1
    """With ``--pool``: the first this-many evaluations are the baseline's runs (seeds of
    one recipe), pooled like the method's, e.g. ``compare noc_s2 noc_s4 ours_s2 ours_s4
    --pool --baseline-runs 2`` gives mean(ours) − mean(no-com) with an interval that
    resamples both recipes' seeds, each independently (for runs paired by seed, e.g. one
    checkpoint with and without ``--mute``, the interval is wider than a paired one)."""
    json: bool = False
    """Print JSON (a list, one object per compared evaluation) instead of Markdown."""

    def run(self) -> int:
        """Read the records, check they pair up, bootstrap, print."""
        if len(self.evaluations) < 2:
            raise CollavnError("give at least two evaluations: BASELINE METHOD [METHOD ...]")
        k = self.baseline_runs
        if k < 1:
            raise CollavnError(f"--baseline-runs must be ≥ 1, got {k}")
        if k > 1 and not self.pool:
            raise CollavnError(f"--baseline-runs {k} pools the baseline's runs: add --pool")
        if len(self.evaluations) <= k:
            raise CollavnError(f"--baseline-runs {k} takes the first {k} evaluations as the "
                               f"baseline; give at least one more ({len(self.evaluations)} "
                               f"given)")
        names = _names(self.evaluations)
        records = [_records(path) for path in self.evaluations]
        if self.pool:
            comparisons = [compare_recipes(records[:k], records[k:], _pooled_name(names[:k]),
                                           _pooled_name(names[k:]), self.samples, self.seed)]
        else:
            comparisons = [compare_records(records[0], other, names[0], name, self.samples,
                                           self.seed)
                           for name, other in zip(names[1:], records[1:], strict=True)]
        if self.json:
            print(json.dumps([c.to_json() for c in comparisons], indent=2))
        else:
            print(comparisons_to_markdown(comparisons))
        return 0


def _records(path: Path) -> list[AgentRecord]:
    """Records of an evaluation directory or file; refuses an ambiguous directory."""
    if path.is_dir():
        file = path / "records.jsonl"
        if not file.is_file():
            several = sorted(p.name for p in path.glob("records_*.jsonl"))
            hint = f" (it holds {', '.join(several)}: pass one)" if several else ""
            raise CollavnError(f"no records.jsonl in {path}{hint}: run `collavn evaluate` "
                               f"first")
        path = file
    if not path.is_file():
        raise CollavnError(f"no evaluation at {path}")
    records = read_records(path)
    if not records:
        raise CollavnError(f"{path} holds no records")
    return records


def _pooled_name(names: list[str]) -> str:
    """``name`` for one run, ``mean of R: a, b, …`` for several."""
    return names[0] if len(names) == 1 else f"mean of {len(names)}: {', '.join(names)}"


def _names(paths: tuple[Path, ...]) -> list[str]:
    """Short names (directory or file stem), the full paths if those collide."""
    short = [p.name if p.is_dir() else p.stem for p in paths]
    return short if len(set(short)) == len(short) else [str(p) for p in paths]
