"""Paired bootstrap comparisons: hand-computed differences, a slow reference, refusals."""

import json

import numpy as np
import pytest

from collavn.cli import main
from collavn.errors import CollavnError
from collavn.evaluation.compare import (
    check_same_episodes,
    compare_pooled,
    compare_recipes,
    compare_records,
    episode_scores,
    paired_bootstrap,
    pooled_bootstrap,
)
from collavn.evaluation.runner import write_records
from collavn.metrics import AgentRecord, compute_metrics


def records(outcomes: dict[str, tuple[str, tuple[int, ...]]], path: float) -> list[AgentRecord]:
    """``{episode: (difficulty, success per agent)}``; start 2 m, a success ends 0.5 m
    from the goal after driving ``path`` metres, a failure ends 2.5 m away after 3 m."""
    return [AgentRecord(eid, n, diff, bool(s), 10 if s else 80, path if s else 3.0, 2.0,
                        0.5 if s else 2.5)
            for eid, (diff, successes) in outcomes.items() for n, s in enumerate(successes)]


A = records({"e1": ("easy", (1, 0)), "e2": ("easy", (0, 0)), "e3": ("easy", (1, 1)),
             "e4": ("easy", (0, 0)), "e5": ("medium", (0, 0)), "e6": ("medium", (1, 0))},
            path=2.0)
B = records({"e1": ("easy", (1, 1)), "e2": ("easy", (1, 0)), "e3": ("easy", (1, 1)),
             "e4": ("easy", (0, 1)), "e5": ("medium", (1, 1)), "e6": ("medium", (1, 0))},
            path=4.0)


def test_differences_match_a_hand_computation_and_lie_in_their_intervals():
    c = compare_records(A, B, "a", "b", samples=2000, seed=1)
    # easy: SR 3/8 → 6/8. SPL: A's successes drove l_g (term 1), B's twice l_g (term ½):
    # 3/8 → 3/8. DTS: failures end 1.5 m outside the radius: A 5·1.5/8 → B 2·1.5/8.
    expected = {"easy": {"SR": (3 / 8, 6 / 8), "SPL": (3 / 8, 3 / 8),
                         "DTS": (7.5 / 8, 3 / 8)},
                "medium": {"SR": (1 / 4, 3 / 4), "SPL": (1 / 4, 3 / 8),
                           "DTS": (4.5 / 4, 1.5 / 4)},
                "overall": {"SR": (4 / 12, 9 / 12), "SPL": (4 / 12, 4.5 / 12),
                            "DTS": (12 / 12, 4.5 / 12)}}
    assert set(c.groups) == set(expected)  # no hard episodes: no hard row
    assert c.episodes == {"easy": 4, "medium": 2, "overall": 6}
    for group, metrics in expected.items():
        for m, (a, b) in metrics.items():
            d = c.groups[group][m]
            assert (d.a, d.b, d.delta) == pytest.approx((a, b, b - a)), (group, m)
            assert d.low <= d.delta <= d.high, (group, m)
    assert c.groups["overall"]["SR"].low >= 0  # B succeeds in every episode A does


def test_bootstrap_matches_a_slow_reference_over_record_lists():
    a, b = episode_scores(A), episode_scores(B)
    fast = paired_bootstrap(a, b, samples=300, rng=np.random.default_rng(7))
    ids = list(a.episode_ids)
    by_episode = {name: {eid: [r for r in recs if r.episode_id == eid] for eid in ids}
                  for name, recs in (("a", A), ("b", B))}
    idx = np.random.default_rng(7).integers(0, len(ids), size=(300, len(ids)))
    deltas = {m: [] for m in ("SR", "SPL", "DTS")}
    for row in idx:
        ma, mb = (compute_metrics([r for k in row for r in by_episode[name][ids[k]]])
                  for name in ("a", "b"))
        for m in deltas:
            deltas[m].append(mb[m] - ma[m])
    for m, values in deltas.items():
        low, high = np.percentile(values, [2.5, 97.5])
        assert (fast[m].low, fast[m].high) == pytest.approx((low, high)), m


def test_identical_evaluations_differ_by_exactly_zero():
    c = compare_records(A, A, samples=100)
    for diffs in c.groups.values():
        for d in diffs.values():
            assert d.delta == d.low == d.high == 0.0


def test_refuses_different_episode_sets_naming_the_missing_ones():
    fewer = [r for r in B if r.episode_id != "e4"]
    extra = records({"e9": ("easy", (1, 1))}, path=2.0)
    with pytest.raises(CollavnError, match=r"different episode sets: 1 episode\(s\) only in "
                                           r"a \(e\.g\. e4\); 1 episode\(s\) only in b "
                                           r"\(e\.g\. e9\)"):
        check_same_episodes(A, fewer + extra, "a", "b")
    with pytest.raises(CollavnError, match="only in a"):
        check_same_episodes(A, [r for r in B if (r.episode_id, r.agent) != ("e2", 1)], "a", "b")


def test_refuses_different_datasets():
    other = [AgentRecord("val/x/" + r.episode_id, r.agent, r.difficulty, r.success, r.steps,
                         r.path_length, r.start_distance, r.final_distance) for r in B]
    with pytest.raises(CollavnError, match=r"different datasets \(no episode in common\)"):
        check_same_episodes(A, other, "a", "b")
    moved = [AgentRecord(r.episode_id, r.agent, r.difficulty, r.success, r.steps,
                         r.path_length, r.start_distance + 0.5, r.final_distance) for r in B]
    with pytest.raises(CollavnError, match="share episode ids but not episodes"):
        check_same_episodes(A, moved, "a", "b")


def test_cli_compare_markdown_json_and_refusal(tmp_path, capsys):
    for name, recs in (("base", A), ("new", B), ("other", B[:-2])):
        write_records(tmp_path / name / "records.jsonl", recs)
    dirs = [str(tmp_path / n) for n in ("base", "new")]
    assert main(["compare", *dirs, "--samples", "200", "--json"]) == 0
    [out] = json.loads(capsys.readouterr().out)
    assert (out["baseline"], out["method"], out["samples"]) == ("base", "new", 200)
    assert out["groups"]["overall"]["SR"]["delta"] == pytest.approx(5 / 12)
    assert main(["compare", *dirs, "--samples", "200"]) == 0
    table = capsys.readouterr().out
    assert "| new | base | overall | 6 | 0.333 → 0.750 | +0.417 [" in table
    assert main(["compare", dirs[0], str(tmp_path / "other")]) == 2
    assert "1 episode(s) only in base (e.g. e6)" in capsys.readouterr().err


def test_single_evaluation_interval_contains_its_value_and_narrows_with_more_episodes():
    from collavn.evaluation.compare import sr_interval
    from collavn.metrics import AgentRecord

    def recs(k):
        return [AgentRecord(episode_id=f"e{i}", agent=a, difficulty="easy",
                            success=(i + a) % 3 != 0, steps=10, path_length=2.0,
                            start_distance=2.0, final_distance=0.5, collisions=0)
                for i in range(k) for a in range(2)]

    small, big = sr_interval(recs(30), 2000, 0), sr_interval(recs(300), 2000, 0)
    for value, low, high, _ in (small, big):
        assert low <= value <= high
    assert small[3] == 30 and big[3] == 300
    assert small[0] == pytest.approx(40 / 60)
    assert big[2] - big[1] < small[2] - small[1]


def test_pooled_copies_of_one_run_equal_the_paired_comparison():
    a, b = episode_scores(A), episode_scores(B)
    paired = paired_bootstrap(a, b, samples=1500, rng=np.random.default_rng(3))
    pooled = pooled_bootstrap(a, [b, b, b], samples=1500, rng=np.random.default_rng(3),
                              run_rng=np.random.default_rng(4))
    assert pooled == paired  # same episode draws; every run draw picks the same values


def test_pooled_value_is_the_runs_mean_and_the_interval_holds_their_spread():
    every = {f"e{i}": ("easy", (1, 1)) for i in range(40)}
    none = {e: ("easy", (0, 0)) for e in every}
    base, good, bad = records(none, 2.0), records(every, 2.0), records(none, 2.0)
    c = compare_pooled(base, [good, bad], "base", "both", samples=2000, seed=0)
    d = c.groups["easy"]["SR"]
    assert (d.a, d.b, d.delta) == (0.0, 0.5, 0.5)
    # episodes all alike: only the run draws vary, {good,good}, {good,bad}, {bad,bad}
    assert (d.low, d.high) == (0.0, 1.0)
    one = compare_pooled(base, [good], "base", "good", samples=200).groups["easy"]["SR"]
    assert (one.delta, one.low, one.high) == (1.0, 1.0, 1.0)
    with pytest.raises(CollavnError, match=r"base and both\[1\] were evaluated on different"):
        compare_pooled(base, [good, bad[:-1]], "base", "both")


def test_pooled_baseline_copies_of_one_run_equal_one_baseline():
    a, b = episode_scores(A), episode_scores(B)
    one = pooled_bootstrap(a, [b, a], samples=1500, rng=np.random.default_rng(3),
                           run_rng=np.random.default_rng(4))
    copies = pooled_bootstrap([a, a, a], [b, a], samples=1500, rng=np.random.default_rng(3),
                              run_rng=np.random.default_rng(4),
                              baseline_rng=np.random.default_rng(5))
    assert copies == one  # the same draws; every baseline draw picks the same values
    assert compare_recipes([A], [B], "a", "b", samples=300, seed=2) == \
        compare_records(A, B, "a", "b", samples=300, seed=2)


def test_two_recipes_pooled_value_is_the_difference_of_means_and_holds_both_spreads():
    every = {f"e{i}": ("easy", (1, 1)) for i in range(40)}
    none = {e: ("easy", (0, 0)) for e in every}
    good, bad = records(every, 2.0), records(none, 2.0)
    c = compare_recipes([bad, good], [good], "base", "method", samples=2000, seed=0)
    d = c.groups["easy"]["SR"]
    assert (d.a, d.b, d.delta) == (0.5, 1.0, 0.5)
    # episodes all alike: only the baseline's run draws vary, {bad,bad} … {good,good}
    assert (d.low, d.high) == (0.0, 1.0)
    with pytest.raises(CollavnError, match=r"base\[0\] and base\[1\] were evaluated on"):
        compare_recipes([bad, good[:-1]], [good], "base", "method")
    with pytest.raises(CollavnError, match="no baseline runs"):
        compare_recipes([], [good])


def test_cli_compare_two_recipes(tmp_path, capsys):
    for name, recs in (("n1", A), ("n2", A), ("o1", B), ("o2", A)):
        write_records(tmp_path / name / "records.jsonl", recs)
    dirs = [str(tmp_path / n) for n in ("n1", "n2", "o1", "o2")]
    assert main(["compare", *dirs, "--pool", "--baseline-runs", "2", "--samples", "200",
                 "--json"]) == 0
    [out] = json.loads(capsys.readouterr().out)
    assert (out["baseline"], out["method"]) == ("mean of 2: n1, n2", "mean of 2: o1, o2")
    assert out["groups"]["overall"]["SR"]["delta"] == pytest.approx(5 / 24)
    for args, message in (([*dirs, "--baseline-runs", "2"], "add --pool"),
                          ([*dirs[:2], "--pool", "--baseline-runs", "2"], "give at least one"),
                          ([*dirs, "--pool", "--baseline-runs", "0"], "must be ≥ 1")):
        assert main(["compare", *args]) == 2
        assert message in capsys.readouterr().err


def test_cli_compare_pool(tmp_path, capsys):
    for name, recs in (("base", A), ("s1", B), ("s2", A)):
        write_records(tmp_path / name / "records.jsonl", recs)
    dirs = [str(tmp_path / n) for n in ("base", "s1", "s2")]
    assert main(["compare", *dirs, "--pool", "--samples", "200", "--json"]) == 0
    [out] = json.loads(capsys.readouterr().out)
    assert out["method"] == "mean of 2: s1, s2"
    # s1 is +5/12 over the baseline, s2 is the baseline: the mean is +5/24
    assert out["groups"]["overall"]["SR"]["delta"] == pytest.approx(5 / 24)
