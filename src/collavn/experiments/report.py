"""``report.md`` of an experiment: the paper's table with intervals, comparisons, pictures.

Sections: the setting and budget; the CommonGoal table in the paper's layout (SR / DTS
/ SPL / SSR by difficulty) with each method's SR and its 95 % interval (bootstrap over
episodes); communication rates; Ad-hoCoop; the paired comparisons the paper's claims
rest on; training curves and a bar chart of SR (PNG); every command that was run.
"""

from __future__ import annotations

import shlex
from datetime import date
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from collavn.evaluation.benchmark import communication_table
from collavn.evaluation.compare import Comparison, compare_records, comparisons_to_markdown
from collavn.evaluation.compare import sr_interval as interval
from collavn.evaluation.runner import read_records
from collavn.metrics import metrics_table

if TYPE_CHECKING:
    from collavn.experiments.pipeline import ExperimentConfig, Stage

#: The comparisons the paper's ordering rests on: (baseline, method).
PAIRS = (("no-com", "ours"), ("no-mem", "ours"), ("il", "no-com"), ("random", "il"))


def write_report(cfg: ExperimentConfig, stages: list[Stage]) -> Path:
    """Write ``OUT/report.md`` (and its PNGs) from the finished stages."""
    from collavn.experiments.pipeline import BASELINES, LEARNED

    out = cfg.out
    records = {name: read_records(out / "eval" / name / "records.jsonl")
               for name in (*LEARNED, *BASELINES)}
    by_name = {s.name: s for s in stages}
    learned = {m: records[m] for m in LEARNED}
    best = max(learned, key=lambda m: float(np.mean([r.success for r in learned[m]])))
    pairs = [*PAIRS, ("explorer", best)]
    comparisons = [compare_records(records[a], records[b], a, b, samples=cfg.samples,
                                   seed=cfg.seed) for a, b in pairs]
    intervals = {name: interval(recs, cfg.samples, cfg.seed) for name, recs in records.items()}
    adhoc = read_records(out / "eval" / f"ours-n{cfg.adhoc_agents}" / "records.jsonl")
    bar = _bar_chart(intervals, out / "sr.png")
    curves = _training_curves(out, LEARNED, out / "training.png")
    lines = [
        f"# The paper's table, `{cfg.preset}` preset, {cfg.budget_minutes:g} min budget",
        "",
        f"Measured {date.today().isoformat()}. CommonGoal, N = {cfg.agents}, test split "
        f"({len(cfg.test_scenes) or 5} scenes × 3 difficulties × {cfg.episodes} episodes); "
        f"training "
        f"{cfg.train_minutes:.1f} min per method. Metrics: SR; DTS floored at 0; SPL; "
        f"SSR (> 1 by design). Intervals: 95 % bootstrap over episodes "
        f"({cfg.samples} resamples), agents of an episode resampled together.",
        "",
        "## CommonGoal",
        "",
        metrics_table(records).to_markdown(),
        "",
        "| method | SR | 95 % interval | episodes |",
        "|---|---:|---:|---:|",
        *[f"| {n} | {sr:.3f} | [{lo:.3f}, {hi:.3f}] | {k} |"
          for n, (sr, lo, hi, k) in intervals.items()],
        "",
        f"![SR with 95 % intervals]({bar.name})",
        "",
        "## Communication",
        "",
        communication_table({m: by_name[f"eval-{m}"].result.get("communication", {})
                             for m in (*LEARNED, *BASELINES)}),
        "",
        f"## Ad-hoCoop: `ours` trained with N = {cfg.agents}, evaluated with N = "
        f"{cfg.adhoc_agents}",
        "",
        metrics_table({f"ours (N={cfg.adhoc_agents})": adhoc}).to_markdown(),
        "",
        communication_table({f"ours (N={cfg.adhoc_agents})":
                             by_name["eval-adhoc-ours"].result.get("communication", {})}),
        "",
        "## Comparisons (method − baseline, paired over the same episodes)",
        "",
        comparisons_to_markdown(comparisons),
        "",
        _verdict(comparisons, best),
        "",
        "## Training",
        "",
        *[f"- `{m}`: {_training_line(by_name[f'train-{m}'].result)}" for m in LEARNED],
        "",
        f"![training curves]({curves.name})" if curves.is_file() else "(no training curves)",
        "",
        "## Commands",
        "",
        "```bash",
        *[shlex.join(s.command) + ("   # resumed" if s.result.get("resumed") else "")
          for s in stages],
        "```",
        "",
        "Stage times (s): " + ", ".join(f"{s.name} {s.seconds:.0f}" for s in stages),
    ]
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path


def _training_line(result: dict[str, Any]) -> str:
    return (f"{result.get('iterations', 0)} updates, {result.get('agent_steps', 0):,} "
            f"agent-steps, training SR {result.get('success_rate', float('nan')):.3f}")


def _verdict(comparisons: list[Comparison], best: str) -> str:
    """One sentence per comparison: does its SR interval exclude zero, which way."""
    lines = []
    for c in comparisons:
        d = c.groups["overall"]["SR"]
        if d.low > 0:
            word = "higher, the interval excludes 0"
        elif d.high < 0:
            word = "lower, the interval excludes 0"
        else:
            word = "not distinguishable from 0 at this size"
        lines.append(f"- SR `{c.method}` − `{c.baseline}`: {d.delta:+.3f} "
                     f"[{d.low:+.3f}, {d.high:+.3f}] — {word}.")
    lines.append(f"- Best learned method by SR: `{best}`. The paper's ordering is ours > "
                 f"no-mem > no-com > IL > random.")
    return "\n".join(lines)


def _bar_chart(intervals: dict[str, tuple[float, float, float, int]], path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(intervals)
    sr = np.array([intervals[n][0] for n in names])
    err = np.array([[sr[i] - intervals[n][1], intervals[n][2] - sr[i]]
                    for i, n in enumerate(names)]).T
    fig, ax = plt.subplots(figsize=(7, 3.5), dpi=110)
    ax.bar(names, sr, yerr=err, capsize=4, color="#4c72b0")
    ax.set_ylabel("SR (test, all difficulties)")
    ax.set_ylim(0, 1)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path


def _training_curves(out: Path, methods: tuple[str, ...], path: Path) -> Path:
    """Training success rate against agent-steps per method, from the TensorBoard events."""
    import matplotlib
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5), dpi=110)
    drawn = False
    for method in methods:
        events = EventAccumulator(str(out / "runs" / method))
        events.Reload()
        if "episode/success_rate" not in events.Tags().get("scalars", []):
            continue
        points = events.Scalars("episode/success_rate")
        ax.plot([p.step for p in points], [p.value for p in points], label=method)
        drawn = True
    if drawn:
        ax.set_xlabel("agent-steps")
        ax.set_ylabel("training SR (last 200 episodes)")
        ax.legend()
        fig.tight_layout()
        fig.savefig(path)
    plt.close(fig)
    return path
