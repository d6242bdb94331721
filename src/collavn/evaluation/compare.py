"""Paired comparisons of evaluations on the same episodes: differences with intervals.

Two policies evaluated on the same episodes are compared episode by episode. The
paired bootstrap resamples **episodes** (with replacement), never single agents: the
agents of one episode share a scene, a start and a goal, so they are not independent
and are resampled together. For each resample both policies' metric is recomputed
over the same episodes, and the 2.5 and 97.5 percentiles of the differences form the
95 % interval::

    a, b = read_records("runs/random/records.jsonl"), read_records("runs/ours/records.jsonl")
    comparison = compare_records(a, b, "random", "ours", samples=5000, seed=0)
    comparison.groups["easy"]["SR"]       # Difference(a=0.40, b=0.62, delta=0.22, …)

The difference is always ``method − baseline`` (B − A). Each metric is the mean over
every agent of every resampled episode, exactly as :mod:`collavn.metrics` computes it
(an episode with more agents weighs more). A difficulty is resampled within its own
episodes; ``overall`` resamples all episodes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from collavn.errors import CollavnError
from collavn.metrics import DIFFICULTIES, AgentRecord, compute_metrics

#: Metrics compared by default, in table order (DTS: lower is better).
COMPARED = ("SR", "SPL", "DTS")
#: Resamples drawn at once (bounds memory for large datasets).
_CHUNK = 1000


@dataclass(frozen=True)
class EpisodeScores:
    """Per-episode sums of each agent's metric term, the input of the bootstrap.

    Attributes:
        episode_ids: ``(K,)`` episode ids, sorted.
        difficulty: ``(K,)`` difficulty of each episode.
        agents: ``(K,)`` agent records per episode.
        sums: ``{metric: (K,)}`` sum over the episode's agents of that agent's term
            (e.g. ``τ`` for SR), so a metric over episodes ``I`` is
            ``sums[I].sum() / agents[I].sum()``.
    """

    episode_ids: np.ndarray
    difficulty: np.ndarray
    agents: np.ndarray
    sums: dict[str, np.ndarray]

    def select(self, mask: np.ndarray) -> EpisodeScores:
        """The episodes where ``mask (K,)`` is True."""
        return EpisodeScores(self.episode_ids[mask], self.difficulty[mask],
                             self.agents[mask], {m: v[mask] for m, v in self.sums.items()})


def episode_scores(records: Sequence[AgentRecord], metrics: Sequence[str] = COMPARED,
                   max_steps: int = 80, success_distance: float = 1.0) -> EpisodeScores:
    """Group agent records by episode and sum each agent's metric term per episode."""
    ids = sorted({r.episode_id for r in records})
    index = {eid: k for k, eid in enumerate(ids)}
    agents = np.zeros(len(ids))
    sums = {m: np.zeros(len(ids)) for m in metrics}
    difficulty = np.empty(len(ids), dtype=object)
    for r in records:
        k = index[r.episode_id]
        agents[k] += 1
        difficulty[k] = r.difficulty
        terms = compute_metrics([r], max_steps, success_distance)  # one agent: its term
        for m in metrics:
            sums[m][k] += terms[m]
    return EpisodeScores(np.array(ids, dtype=object), difficulty, agents, sums)


@dataclass(frozen=True)
class Difference:
    """One metric of two policies on the same episodes.

    Attributes:
        a: The baseline's value.
        b: The method's value.
        delta: ``b − a``.
        low: 2.5th percentile of the bootstrapped ``b − a``.
        high: 97.5th percentile.
    """

    a: float
    b: float
    delta: float
    low: float
    high: float


def paired_bootstrap(a: EpisodeScores, b: EpisodeScores, samples: int = 5000,
                     rng: np.random.Generator | None = None,
                     level: float = 0.95) -> dict[str, Difference]:
    """Difference ``b − a`` of every metric with its percentile interval.

    Args:
        a: Baseline scores; same episodes in the same order as ``b``.
        b: Method scores.
        samples: Bootstrap resamples of the ``K`` episodes.
        rng: Draws the resampled episode indices (shared by all metrics).
        level: Coverage of the interval.
    """
    return pooled_bootstrap(a, [b], samples, rng, None, level)


def pooled_bootstrap(a: EpisodeScores | Sequence[EpisodeScores],
                     runs: Sequence[EpisodeScores], samples: int = 5000,
                     rng: np.random.Generator | None = None,
                     run_rng: np.random.Generator | None = None,
                     level: float = 0.95,
                     baseline_rng: np.random.Generator | None = None) -> dict[str, Difference]:
    """Difference between the mean of ``R`` runs of a method and a baseline, with its interval.

    The method's value is the mean of its runs' values (e.g. training seeds of one
    recipe). Each resample draws the ``K`` episodes with replacement (the same for the
    baseline and every run) and, when ``R > 1``, ``R`` of the runs with replacement, so
    the interval holds the spread between runs as well as between episodes; with a
    handful of runs it is itself rough. One run is :func:`paired_bootstrap`. The
    baseline may be several runs too (two recipes over seeds): its value is their mean,
    and its runs are drawn the same way, independently of the method's.

    Args:
        a: Baseline scores, or the baseline's runs (each on the same episodes).
        runs: The method's runs, each on the baseline's episodes in the same order.
        samples: Bootstrap resamples.
        rng: Draws the episode indices (the same draws as :func:`paired_bootstrap`).
        run_rng: Draws the method's run indices (unused for one run).
        level: Coverage of the interval.
        baseline_rng: Draws the baseline's run indices (unused for one baseline run, so
            a single baseline gives the same numbers as without this argument).
    """
    bases = [a] if isinstance(a, EpisodeScores) else list(a)
    if not runs:
        raise CollavnError("no runs to compare")
    if not bases:
        raise CollavnError("no baseline runs to compare against")
    first = bases[0]
    for b in (*bases[1:], *runs):
        if not np.array_equal(first.episode_ids, b.episode_ids):
            raise CollavnError("paired bootstrap needs the same episodes in the same order")
    if len(first.episode_ids) == 0:
        raise CollavnError("no episodes to compare")
    rng = rng or np.random.default_rng(0)
    run_rng = run_rng or np.random.default_rng(1)
    baseline_rng = baseline_rng or np.random.default_rng(2)
    k = len(first.episode_ids)
    stacked = {m: np.stack([b.sums[m] for b in runs]) for m in first.sums}  # (R, K)
    stacked_a = {m: np.stack([b.sums[m] for b in bases]) for m in first.sums}  # (Ra, K)
    deltas: dict[str, list[np.ndarray]] = {m: [] for m in first.sums}
    for start in range(0, samples, _CHUNK):
        n = min(_CHUNK, samples - start)
        idx = rng.integers(0, k, size=(n, k))
        pick = _draw_runs(run_rng, len(runs), n)
        pick_a = _draw_runs(baseline_rng, len(bases), n)
        agents = first.agents[idx].sum(axis=1)
        for m in first.sums:
            method = _resampled_mean(stacked[m], idx, pick)
            baseline = _resampled_mean(stacked_a[m], idx, pick_a)
            deltas[m].append((method - baseline) / agents)
    tail = 100 * (1 - level) / 2
    out = {}
    for m in first.sums:
        va = float(np.mean([b.sums[m].sum() / b.agents.sum() for b in bases]))
        vb = float(np.mean([b.sums[m].sum() / b.agents.sum() for b in runs]))
        low, high = np.percentile(np.concatenate(deltas[m]), [tail, 100 - tail])
        out[m] = Difference(va, vb, vb - va, float(low), float(high))
    return out


def _draw_runs(rng: np.random.Generator, r: int, n: int) -> np.ndarray:
    """``(n, r)`` run indices drawn with replacement; one run draws nothing."""
    return rng.integers(0, r, size=(n, r)) if r > 1 else np.zeros((n, 1), int)


def _resampled_mean(sums: np.ndarray, idx: np.ndarray, pick: np.ndarray) -> np.ndarray:
    """Mean over the drawn runs ``pick (n, R')`` of each run's sum over episodes ``idx``."""
    totals = sums[:, idx].sum(axis=-1).T  # (n, R): each run's resampled sum
    return np.take_along_axis(totals, pick, axis=1).mean(axis=1)


def check_same_episodes(a: Sequence[AgentRecord], b: Sequence[AgentRecord], name_a: str = "A",
                        name_b: str = "B", examples: int = 3) -> None:
    """Refuse to pair evaluations of different datasets or episode sets, saying which.

    Compares the sets of ``(episode_id, agent)`` keys, then, for the shared keys, the
    difficulty and geodesic start distance (same ids from a regenerated dataset).
    """
    keys_a, keys_b = _keys(a, name_a), _keys(b, name_b)
    if keys_a.keys() != keys_b.keys():
        only_a = sorted({eid for eid, _ in keys_a.keys() - keys_b.keys()})
        only_b = sorted({eid for eid, _ in keys_b.keys() - keys_a.keys()})
        common = {eid for eid, _ in keys_a.keys() & keys_b.keys()}
        what = ("different datasets (no episode in common)" if not common else
                "different episode sets")
        parts = [f"{len(ids)} episode(s) only in {name} (e.g. {', '.join(ids[:examples])})"
                 for name, ids in ((name_a, only_a), (name_b, only_b)) if ids]
        raise CollavnError(f"{name_a} and {name_b} were evaluated on {what}: "
                           + "; ".join(parts))
    differ = sorted({key[0] for key, ra in keys_a.items()
                     if (ra.difficulty, round(ra.start_distance, 3))
                     != (keys_b[key].difficulty, round(keys_b[key].start_distance, 3))})
    if differ:
        raise CollavnError(f"{name_a} and {name_b} share episode ids but not episodes "
                           f"(different datasets): {len(differ)} episode(s) differ in "
                           f"difficulty or start distance (e.g. {', '.join(differ[:examples])})")


def _keys(records: Sequence[AgentRecord], name: str) -> dict[tuple[str, int], AgentRecord]:
    out: dict[tuple[str, int], AgentRecord] = {}
    for r in records:
        key = (r.episode_id, r.agent)
        if key in out:
            raise CollavnError(f"{name} has two records of episode {r.episode_id} agent "
                               f"{r.agent}")
        out[key] = r
    return out


@dataclass(frozen=True)
class Comparison:
    """Method vs baseline per difficulty and overall.

    Attributes:
        baseline: Name of A.
        method: Name of B.
        groups: ``{"easy" | "medium" | "hard" | "overall": {metric: Difference}}``;
            difficulties without episodes are left out.
        episodes: ``{group: episodes compared}``.
        samples: Bootstrap resamples.
        seed: Seed of the resampling.
    """

    baseline: str
    method: str
    groups: dict[str, dict[str, Difference]]
    episodes: dict[str, int]
    samples: int
    seed: int

    def to_json(self) -> dict[str, Any]:
        """Plain JSON: ``{"baseline", "method", "samples", "seed", "groups": {...}}``."""
        return {"baseline": self.baseline, "method": self.method, "samples": self.samples,
                "seed": self.seed, "difference": "method - baseline",
                "groups": {g: {"episodes": self.episodes[g],
                               **{m: vars(d) for m, d in diffs.items()}}
                           for g, diffs in self.groups.items()}}


def compare_records(a: Sequence[AgentRecord], b: Sequence[AgentRecord], name_a: str = "A",
                    name_b: str = "B", samples: int = 5000, seed: int = 0,
                    metrics: Sequence[str] = COMPARED) -> Comparison:
    """Check that ``a`` and ``b`` cover the same episodes, then bootstrap ``b − a``.

    Each group draws from its own generator, ``default_rng([seed, group index])``, so a
    difficulty's interval does not depend on which other difficulties are present.
    """
    return compare_pooled(a, [b], name_a, name_b, samples, seed, metrics)


def compare_pooled(a: Sequence[AgentRecord], runs: Sequence[Sequence[AgentRecord]],
                   name_a: str = "A", name_b: str = "B", samples: int = 5000, seed: int = 0,
                   metrics: Sequence[str] = COMPARED) -> Comparison:
    """The mean of several runs of a method against ``a``, resampling episodes and runs.

    As :func:`compare_records` (which is this with one run), with
    :func:`pooled_bootstrap`; the runs are drawn by ``default_rng([seed, group index,
    1])``. Every run must cover ``a``'s episodes.
    """
    return compare_recipes([a], runs, name_a, name_b, samples, seed, metrics)


def compare_recipes(baselines: Sequence[Sequence[AgentRecord]],
                    runs: Sequence[Sequence[AgentRecord]], name_a: str = "A",
                    name_b: str = "B", samples: int = 5000, seed: int = 0,
                    metrics: Sequence[str] = COMPARED) -> Comparison:
    """The mean of a method's runs against the mean of a baseline's runs (seeds of two recipes).

    As :func:`compare_pooled` (which is this with one baseline run); the baseline's runs
    are drawn by ``default_rng([seed, group index, 2])``, independently of the method's.
    Every run of either must cover the first baseline run's episodes.
    """
    if samples < 1:
        raise CollavnError(f"samples must be ≥ 1, got {samples}")
    if not baselines:
        raise CollavnError("no baseline runs to compare against")
    if not runs:
        raise CollavnError("no runs to compare")
    a = baselines[0]
    first_a = name_a if len(baselines) == 1 else f"{name_a}[0]"
    for i, other in enumerate(baselines[1:], start=1):
        check_same_episodes(a, other, first_a, f"{name_a}[{i}]")
    for i, run in enumerate(runs):
        check_same_episodes(a, run, first_a, name_b if len(runs) == 1 else f"{name_b}[{i}]")
    scores_a = [episode_scores(base, metrics) for base in baselines]
    scores_runs = [episode_scores(run, metrics) for run in runs]
    groups, episodes = {}, {}
    for g, group in enumerate((*DIFFICULTIES, "overall")):
        mask = (np.ones(len(scores_a[0].episode_ids), bool) if group == "overall"
                else scores_a[0].difficulty == group)
        if not mask.any():
            continue
        groups[group] = pooled_bootstrap(
            [sc.select(mask) for sc in scores_a], [sc.select(mask) for sc in scores_runs],
            samples, np.random.default_rng([seed, g]), np.random.default_rng([seed, g, 1]),
            baseline_rng=np.random.default_rng([seed, g, 2]))
        episodes[group] = int(mask.sum())
    return Comparison(name_a, name_b, groups, episodes, samples, seed)


def comparisons_to_markdown(comparisons: Sequence[Comparison]) -> str:
    """One table: a row per comparison and group, ``baseline → method`` and ``Δ [95 % CI]``."""
    if not comparisons:
        return ""
    first = comparisons[0]
    metrics = list(next(iter(first.groups.values())))
    lines = [f"Paired bootstrap over episodes ({first.samples} resamples, seed {first.seed}): "
             f"Δ = method − baseline, 95 % percentile interval.", ""]
    header = ["method", "baseline", "difficulty", "episodes"] + [
        f"{m} (baseline → method) | Δ{m} [95 % CI]" for m in metrics]
    lines.append("| " + " | ".join(header) + " |")
    lines.append("|" + "|".join([":---", ":---", ":---", "---:"] + ["---:|---:"] * len(metrics))
                 + "|")
    for c in comparisons:
        for group, diffs in c.groups.items():
            cells = [c.method, c.baseline, group, str(c.episodes[group])]
            for m in metrics:
                d = diffs[m]
                cells.append(f"{d.a:.3f} → {d.b:.3f} | {d.delta:+.3f} "
                             f"[{d.low:+.3f}, {d.high:+.3f}]")
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def sr_interval(records: Sequence[AgentRecord], samples: int = 5000, seed: int = 0,
                metric: str = "SR") -> tuple[float, float, float, int]:
    """One evaluation's metric with its 95 % bootstrap interval over episodes.

    The paired bootstrap against an all-zero baseline on the same episodes, so one
    resampling code serves both.

    Returns:
        ``(value, low, high, episodes)``.
    """
    scores = episode_scores(records, (metric,))
    zero = EpisodeScores(scores.episode_ids, scores.difficulty, scores.agents,
                         {metric: np.zeros_like(scores.sums[metric])})
    d = paired_bootstrap(zero, scores, samples, np.random.default_rng(seed))[metric]
    return d.b, d.low, d.high, len(scores.episode_ids)
