"""SR / DTS / SPL / SSR against values computed by hand, and the table renderings."""

from __future__ import annotations

import csv
import io
import math

import pytest

from collavn.metrics import (
    AgentRecord,
    compute_metrics,
    distance_to_success,
    metrics_table,
    search_metrics,
    search_table,
    spl,
    ssr,
    success_rate,
)


def rec(ep: str, agent: int, diff: str, ok: bool, steps: int, path: float, lg: float,
        final: float) -> AgentRecord:
    return AgentRecord(ep, agent, diff, ok, steps, path, lg, final, collisions=0)


# Three 2-agent episodes, mixed success. Per record (T = 80):
#                         τ   DTS        SPL            SSR
RECORDS = [
    rec("e1", 0, "easy", True, 10, 4.0, 2.0, 0.5),    # 1   0 (floor)  2/4 = 0.5      80/10 = 8
    rec("e1", 1, "easy", False, 80, 3.0, 2.5, 1.8),   # 0   0.8        0              0
    rec("e2", 0, "medium", True, 40, 3.5, 4.0, 0.9),  # 1   0 (floor)  4/4 = 1        80/40 = 2
    rec("e2", 1, "medium", True, 20, 5.0, 4.0, 1.0),  # 1   0          4/5 = 0.8      80/20 = 4
    rec("e3", 0, "hard", False, 80, 2.0, 6.0, 4.5),   # 0   3.5        0              0
    rec("e3", 1, "hard", True, 80, 7.5, 6.0, 0.2),    # 1   0 (floor)  6/7.5 = 0.8    80/80 = 1
]


def test_overall_values_by_hand():
    assert success_rate(RECORDS) == pytest.approx(4 / 6)
    assert distance_to_success(RECORDS) == pytest.approx((0.8 + 3.5) / 6)
    assert spl(RECORDS) == pytest.approx((0.5 + 1.0 + 0.8 + 0.8) / 6)
    assert ssr(RECORDS) == pytest.approx((8 + 2 + 4 + 1) / 6)
    assert ssr(RECORDS) > 1  # normal: successful agents used far fewer than T steps


def test_dts_is_floored_at_zero():
    # Without the floor (the paper's formula) the agents inside the radius would
    # subtract: (-0.5 + 0.8 - 0.1 + 0 + 3.5 - 0.8) / 6.
    assert distance_to_success(RECORDS) != pytest.approx((-0.5 + 0.8 - 0.1 + 3.5 - 0.8) / 6)
    assert distance_to_success([rec("e", 0, "easy", True, 5, 1, 2, 0.1)]) == 0.0
    assert distance_to_success(RECORDS, success_distance=0.5) == pytest.approx(
        (0 + 1.3 + 0.4 + 0.5 + 4.0 + 0) / 6)


def test_ssr_respects_budget_and_clips():
    # With T = 40 a step count above the budget counts as T: e3/1 → 40/40 = 1.
    assert ssr(RECORDS, max_steps=40) == pytest.approx((4 + 1 + 2 + 1) / 6)
    assert ssr([rec("e", 0, "easy", True, 0, 1, 2, 0.1)]) == 80.0  # at least one step


def test_empty_is_nan():
    assert all(math.isnan(v) for v in compute_metrics([]).values())


def test_table_per_difficulty_and_overall():
    table = metrics_table({"ours": RECORDS, "easy-only": RECORDS[:2]})
    ours = table.rows[0].groups
    assert ours["easy"] == pytest.approx({"SR": 0.5, "DTS": 0.4, "SPL": 0.25, "SSR": 4.0})
    assert ours["medium"] == pytest.approx({"SR": 1.0, "DTS": 0.0, "SPL": 0.9, "SSR": 3.0})
    assert ours["hard"] == pytest.approx({"SR": 0.5, "DTS": 1.75, "SPL": 0.4, "SSR": 0.5})
    assert ours["overall"] == pytest.approx(compute_metrics(RECORDS))
    assert table.rows[0].counts["overall"] == (3, 6)
    assert table.rows[0].counts["easy"] == (1, 2)

    md = table.to_markdown().splitlines()
    assert md[0].startswith("| Method | Easy SR↑ | Easy DTS↓ | Easy SPL↑ | Easy SSR↑ | Medium")
    assert "Overall SSR↑" in md[0]
    assert md[2].startswith("| ours | 0.500 | 0.40 | 0.250 | 4.00 | 1.000 | 0.00 | 0.900 |")
    assert md[3].startswith("| easy-only | 0.500 | 0.40 | 0.250 | 4.00 | – | – |")

    tex = table.to_latex()
    assert r"\multicolumn{4}{c}{Easy}" in tex and r"\multicolumn{4}{c}{Overall}" in tex
    assert "easy-only & 0.500 & 0.40" in tex
    assert " -- " in tex and "–" not in tex

    rows = list(csv.DictReader(io.StringIO(table.to_csv())))
    assert len(rows) == 2 * 4
    hard = next(r for r in rows if r["method"] == "ours" and r["difficulty"] == "hard")
    assert float(hard["DTS"]) == pytest.approx(1.75) and hard["episodes"] == "1"
    missing = next(r for r in rows if r["method"] == "easy-only" and r["difficulty"] == "hard")
    assert math.isnan(float(missing["SR"]))


def test_single_method_table():
    table = metrics_table(RECORDS, max_steps=80)
    assert len(table.rows) == 1 and table.rows[0].method == ""
    assert table.rows[0].groups["overall"]["SSR"] == pytest.approx(2.5)


def test_search_and_homing_split_by_hand():
    from dataclasses import replace

    sighted = [3, -1, 0, 12, -1, None]  # per RECORDS row; None: not measured
    recs = [replace(r, sighted_step=s) for r, s in zip(RECORDS, sighted, strict=True)]
    m = search_metrics(recs)
    # measured: rows 0-4; sighted: rows 0, 2, 3 (τ = 1, 1, 1); never: rows 1, 4 (τ = 0, 0)
    assert m["agents"] == 5
    assert m["sighted"] == pytest.approx(3 / 5)
    assert m["homing"] == pytest.approx(1.0)
    assert m["unsighted SR"] == pytest.approx(0.0)
    assert math.isnan(m["failed homing collisions"])  # every sighted agent succeeded
    recs[0] = replace(recs[0], success=False, collisions=7)
    recs[2] = replace(recs[2], collisions=30)  # a success: its collisions do not count
    assert search_metrics(recs)["homing"] == pytest.approx(2 / 3)
    assert search_metrics(recs)["failed homing collisions"] == pytest.approx(7.0)
    # failed, sighted or not: rows 0 (final 0.5 m, 4.0 m driven, 7 collisions), 1 (1.8,
    # 3.0, 0) and 4 (4.5, 2.0, 0); row 5 failed too but is not measured
    failure = search_metrics(recs)
    assert failure["failed distance"] == pytest.approx(1.8)
    assert failure["failed path"] == pytest.approx(3.0)
    assert failure["failed collisions"] == pytest.approx(7 / 3)
    unmeasured = search_metrics(RECORDS)  # none measured
    assert unmeasured.pop("agents") == 0
    assert all(math.isnan(v) for v in unmeasured.values())
    table = search_table({"m": recs})
    # easy: rows 0 (now failed) and 1; hard: row 4 (row 5 is unmeasured)
    assert "| m | easy | 2 | 0.500 | 0.000 | 0.000 | 7.0 | 1.15 | 3.5 | 3.5 |" in table
    assert "| m | hard | 1 | 0.000 | – | 0.000 | – | 4.50 | 2.0 | 0.0 |" in table
    assert "| m | overall | 5 | 0.600 | 0.667 | 0.000 | 7.0 | 1.80 | 3.0 | 2.3 |" in table
