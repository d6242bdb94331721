"""SR, DTS, SPL and SSR as pure functions over per-agent episode records, plus tables.

Every metric averages over all ``K`` episodes × ``N`` agents: one :class:`AgentRecord`
per agent per episode, success ``τ ∈ {0, 1}``. The paper's table reports them per
difficulty (easy / medium / hard); we add an overall column::

    records = [AgentRecord("val/procedural:100/00000", 0, "easy", True, 12, 4.1, 2.3, 0.8)]
    print(metrics_table(records).to_markdown())
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from collavn.datasets.episode import DIFFICULTY_BINS

#: Difficulty names in table order.
DIFFICULTIES = tuple(DIFFICULTY_BINS)
#: Metric names in table order; ↑ higher is better, ↓ lower is better.
METRICS = ("SR", "DTS", "SPL", "SSR")
_ARROWS = {"SR": "↑", "DTS": "↓", "SPL": "↑", "SSR": "↑"}
_LATEX_ARROWS = {"SR": r"$\uparrow$", "DTS": r"$\downarrow$", "SPL": r"$\uparrow$",
                 "SSR": r"$\uparrow$"}
_DIGITS = {"SR": 3, "DTS": 2, "SPL": 3, "SSR": 2}


@dataclass(frozen=True)
class AgentRecord:
    """What one agent did in one episode: the input of every metric.

    Attributes:
        episode_id: Identity of the episode (unique within a dataset).
        agent: Index of the agent in the episode.
        difficulty: ``easy``, ``medium`` or ``hard`` (geodesic start-to-goal bin).
        success: ``τ``: the agent ended within the success distance of its goal.
        steps: ``T_kn``: steps the agent used (``T`` if it never succeeded).
        path_length: ``l``: metres actually driven.
        start_distance: ``l_g``: geodesic start-to-goal distance in metres.
        final_distance: Geodesic distance to the goal at the end, in metres.
        collisions: Steps on which the agent collided (scene or another agent).
        sighted_step: The first step at which the goal was *in sight* — within
            :data:`SIGHT_DISTANCE` metres, the straight segment to it on navigable cells
            (0: at the start; ``-1``: never; ``None``: not measured, e.g. records
            written before 2026-12-06). It splits an agent's episode into *search*
            (finding the goal) and *homing* (reaching a goal in sight): see
            :func:`search_metrics`.
    """

    episode_id: str
    agent: int
    difficulty: str
    success: bool
    steps: int
    path_length: float
    start_distance: float
    final_distance: float
    collisions: int = 0
    sighted_step: int | None = None


#: An agent has its goal *in sight* within this Euclidean distance (metres) when the
#: straight segment to it is navigable: where ``il``'s expert (the seeker) stops
#: searching and heads for the goal.
SIGHT_DISTANCE = 2.0


def _column(records: Sequence[AgentRecord], name: str) -> np.ndarray:
    return np.array([getattr(r, name) for r in records], dtype=np.float64)


def success_rate(records: Sequence[AgentRecord]) -> float:
    """SR = mean over episodes × agents of ``τ``; NaN for no records."""
    if not records:
        return math.nan
    return float(_column(records, "success").mean())


def distance_to_success(records: Sequence[AgentRecord], success_distance: float = 1.0) -> float:
    """DTS = mean of ``max(0, d_T − success_distance)``, metres; NaN for no records.

    ``d_T`` is the geodesic distance to the goal when the agent's episode ended. The
    paper writes ``d_T − 1.0`` without the floor; we floor at 0 so an agent that stops
    inside the success radius counts as 0, not as a negative distance.
    """
    if not records:
        return math.nan
    d = _column(records, "final_distance")
    return float(np.maximum(d - success_distance, 0.0).mean())


def spl(records: Sequence[AgentRecord]) -> float:
    """SPL = mean of ``τ · l_g / max(l_g, l)``; NaN for no records.

    ``l_g`` is the geodesic start-to-goal distance, ``l`` the path actually driven.
    """
    if not records:
        return math.nan
    tau = _column(records, "success")
    lg = _column(records, "start_distance")
    length = _column(records, "path_length")
    return float((tau * lg / np.maximum(np.maximum(lg, length), 1e-12)).mean())


def ssr(records: Sequence[AgentRecord], max_steps: int = 80) -> float:
    """SSR (success speed rate) = mean of ``τ · T / min(T, T_kn)``; NaN for no records.

    ``T`` is the step budget, ``T_kn`` the steps agent ``n`` used in episode ``k``
    (at least 1). A successful agent scores ``T / T_kn ≥ 1``, so SSR > 1 is normal:
    SSR = 4 means successful agents needed a quarter of the budget on average.
    """
    if not records:
        return math.nan
    tau = _column(records, "success")
    used = np.clip(_column(records, "steps"), 1, max_steps)
    return float((tau * max_steps / used).mean())


def compute_metrics(records: Sequence[AgentRecord], max_steps: int = 80,
                    success_distance: float = 1.0) -> dict[str, float]:
    """All four metrics of ``records`` as ``{"SR", "DTS", "SPL", "SSR"}``."""
    return {"SR": success_rate(records),
            "DTS": distance_to_success(records, success_distance),
            "SPL": spl(records),
            "SSR": ssr(records, max_steps)}


def search_metrics(records: Sequence[AgentRecord]) -> dict[str, float]:
    """Search and homing: where a policy loses its failed episodes.

    ``agents`` — records with a measured ``sighted_step`` (only those count);
    ``sighted`` — the fraction of them that ever had their goal in sight (the search
    found it); ``homing`` — SR of those agents (a goal in sight became a success);
    ``unsighted SR`` — SR of the rest; ``failed homing collisions`` — the mean
    collision steps of the sighted agents that failed (a policy whose mean action
    pushes into a wall near its goal shows here: ~10 of 80 steps for an ``il`` policy,
    up to ~40 for PPO fine-tunes that drove with sampled actions). NaN where a group is
    empty. For scale: the goal-blind explorer homes on ~0.68 of easy val agents that
    sight their goal (by chance), the seeker (which switches to the shortest path at
    the first sighting) on ~0.98.

    And how the failed agents (sighted or not) end: ``failed distance`` — their median
    geodesic distance to the goal at the end (metres), ``failed path`` — the median
    metres they drove, ``failed collisions`` — their mean collision steps. An agent
    still searching ends far after a long drive; one that stalls near its goal (pressed
    against an obstacle, or jerking on the spot) ends near, after a short drive and many
    collisions.
    """
    known = [(r, r.sighted_step) for r in records if r.sighted_step is not None]
    seen = [r for r, step in known if step >= 0]
    unseen = [r for r, step in known if step < 0]
    lost = [r for r in seen if not r.success]
    failed = [r for r, _ in known if not r.success]
    return {"agents": float(len(known)),
            "sighted": len(seen) / len(known) if known else math.nan,
            "homing": success_rate(seen),
            "unsighted SR": success_rate(unseen),
            "failed homing collisions": float(_column(lost, "collisions").mean())
            if lost else math.nan,
            "failed distance": float(np.median(_column(failed, "final_distance")))
            if failed else math.nan,
            "failed path": float(np.median(_column(failed, "path_length")))
            if failed else math.nan,
            "failed collisions": float(_column(failed, "collisions").mean())
            if failed else math.nan}


def search_groups(records: Sequence[AgentRecord]) -> dict[str, dict[str, float]]:
    """:func:`search_metrics` per difficulty and ``overall``."""
    return {g: search_metrics([r for r in records if g == "overall" or r.difficulty == g])
            for g in (*DIFFICULTIES, "overall")}


#: The :func:`search_metrics` keys :func:`search_table` shows: (key, header, format).
SEARCH_COLUMNS = (("sighted", "goal sighted", ".3f"),
                  ("homing", "SR once sighted (homing)", ".3f"),
                  ("unsighted SR", "SR never sighted", ".3f"),
                  ("failed homing collisions", "collision steps, homing failed", ".1f"),
                  ("failed distance", "failed: median m to goal", ".2f"),
                  ("failed path", "failed: median m driven", ".1f"),
                  ("failed collisions", "failed: collision steps", ".1f"))


def search_table(records: Mapping[str, Sequence[AgentRecord]]) -> str:
    """Markdown: per method and difficulty (with measured agents), :func:`search_metrics`."""
    lines = ["| method | difficulty | agents | "
             + " | ".join(header for _, header, _ in SEARCH_COLUMNS) + " |",
             "|---|---|---:|" + "---:|" * len(SEARCH_COLUMNS)]
    for method, recs in records.items():
        for g, m in search_groups(recs).items():
            if not m["agents"]:
                continue
            cells = ["–" if math.isnan(m[k]) else f"{m[k]:{fmt}}"
                     for k, _, fmt in SEARCH_COLUMNS]
            lines.append(f"| {method} | {g} | {int(m['agents'])} | " + " | ".join(cells)
                         + " |")
    return "\n".join(lines) + "\n"


@dataclass(frozen=True)
class MetricsRow:
    """One method's metrics per difficulty and overall.

    Attributes:
        method: Name shown in the first column.
        groups: ``{"easy" | "medium" | "hard" | "overall": {metric: value}}``.
        counts: ``{group: (episodes, agent records)}``.
    """

    method: str
    groups: dict[str, dict[str, float]]
    counts: dict[str, tuple[int, int]]


@dataclass(frozen=True)
class MetricsTable:
    """Rows of methods × (difficulty, metric) columns, in the paper's layout."""

    rows: tuple[MetricsRow, ...]

    @property
    def groups(self) -> tuple[str, ...]:
        """Column groups: the difficulties, then ``overall``."""
        return (*DIFFICULTIES, "overall")

    def _cells(self, row: MetricsRow, missing: str = "–") -> list[str]:
        return [_fmt(row.groups[g][m], m, missing) for g in self.groups for m in METRICS]

    def to_markdown(self) -> str:
        """GitHub Markdown: one header row ``Easy SR↑ … Overall SSR↑``."""
        header = ["Method"] + [f"{g.capitalize()} {m}{_ARROWS[m]}"
                               for g in self.groups for m in METRICS]
        lines = ["| " + " | ".join(header) + " |",
                 "|" + "|".join([":---"] + ["---:"] * (len(header) - 1)) + "|"]
        lines += ["| " + " | ".join([r.method, *self._cells(r)]) + " |" for r in self.rows]
        return "\n".join(lines) + "\n"

    def to_latex(self) -> str:
        """A booktabs ``tabular`` with a multicolumn header per difficulty."""
        n = len(METRICS)
        spec = "l" + ("|" + "c" * n) * len(self.groups)
        top = " & ".join([""] + [rf"\multicolumn{{{n}}}{{c}}{{{g.capitalize()}}}"
                                 for g in self.groups])
        rules = " ".join(rf"\cmidrule(lr){{{2 + i * n}-{1 + (i + 1) * n}}}"
                         for i in range(len(self.groups)))
        sub = " & ".join(["Method"] + [m + _LATEX_ARROWS[m] for _ in self.groups
                                       for m in METRICS])
        body = [" & ".join([_latex_escape(r.method), *self._cells(r, "--")]) + r" \\"
                for r in self.rows]
        return "\n".join([rf"\begin{{tabular}}{{{spec}}}", r"\toprule", top + r" \\", rules,
                          sub + r" \\", r"\midrule", *body, r"\bottomrule",
                          r"\end{tabular}"]) + "\n"

    def to_csv(self) -> str:
        """Long format, full precision: ``method,difficulty,episodes,records,SR,DTS,SPL,SSR``."""
        out = io.StringIO()
        writer = csv.writer(out, lineterminator="\n")
        writer.writerow(["method", "difficulty", "episodes", "records", *METRICS])
        for r in self.rows:
            for g in self.groups:
                writer.writerow([r.method, g, *r.counts[g],
                                 *(repr(r.groups[g][m]) for m in METRICS)])
        return out.getvalue()


def metrics_table(records: Sequence[AgentRecord] | Mapping[str, Sequence[AgentRecord]],
                  max_steps: int = 80, success_distance: float = 1.0) -> MetricsTable:
    """Metrics per difficulty and overall; one row per method.

    Args:
        records: One method's records, or ``{method name: records}`` for several rows.
        max_steps: The step budget ``T`` (paper: 80).
        success_distance: Success radius in metres (paper: 1.0).

    Returns:
        A table rendered with ``to_markdown()``, ``to_latex()`` or ``to_csv()``;
        a difficulty without records shows ``–`` (NaN in CSV).
    """
    by_method = records if isinstance(records, Mapping) else {"": records}
    rows = []
    for method, recs in by_method.items():
        groups: dict[str, dict[str, float]] = {}
        counts: dict[str, tuple[int, int]] = {}
        for g in (*DIFFICULTIES, "overall"):
            sel = [r for r in recs if g == "overall" or r.difficulty == g]
            groups[g] = compute_metrics(sel, max_steps, success_distance)
            counts[g] = (len({r.episode_id for r in sel}), len(sel))
        rows.append(MetricsRow(method, groups, counts))
    return MetricsTable(tuple(rows))


def _fmt(value: float, metric: str, missing: str) -> str:
    return missing if math.isnan(value) else f"{value:.{_DIGITS[metric]}f}"


def _latex_escape(text: str) -> str:
    for ch in "\\&%$#_{}":
        text = text.replace(ch, "\\" + ch)
    return text
