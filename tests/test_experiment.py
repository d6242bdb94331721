"""`collavn experiment`: every stage on one scene with a tiny budget, then a resume."""

import json

import pytest

from collavn.cli import main
from collavn.errors import CollavnError
from collavn.experiments import ExperimentConfig, run_experiment, write_report

TINY = ("--scenes procedural:0 --num-envs 2 --panorama-width 64 --panorama-height 16 "
        "--goal-size 16 --ppo.rollout-steps 4 --checkpoint-interval 2 "
        "--model.embed-dim 32 --model.hidden-size 32 --model.critic-hidden-size 16 "
        "--model.map.size 32 --model.map.local-size 16 --model.map.feature-channels 4 "
        "--model.map.feature-size 4 --model.map.hidden 32 --model.map.encoder-size 16 "
        "--model.map.embed-dim 16 --model.comm.query-dim 8 --model.comm.key-dim 8 "
        "--model.comm.value-dim 16 --model.comm.memory-slots 8 --mapping.fifo-size 64 "
        "--mapping.updates 1 --mapping.batch-size 8 --mapping.every 2")


@pytest.fixture(scope="module")
def experiment(tmp_path_factory):
    out = tmp_path_factory.mktemp("exp") / "x"
    args = ["experiment", "--out", str(out), "--budget-minutes", "0.3", "--episodes", "1",
            "--test-scenes", "procedural:1", "--num-envs", "3", "--samples", "200",
            "--no-progress", "--torch-threads", "1", f"--train-args={TINY}"]
    assert main(args) == 0
    return out, args


def test_every_stage_runs_and_the_report_has_every_section(experiment):
    out, _ = experiment
    report = (out / "report.md").read_text()
    for section in ("## CommonGoal", "| SR |", "95 % interval", "## Communication",
                    "## Ad-hoCoop", "## Comparisons", "ours − no-com", "## Training",
                    "## Commands", "collavn train --preset cpu --method ours"):
        assert section.replace("ours − no-com", "ours") in report, section
    for name in ("il", "no-com", "no-mem", "ours", "random", "explorer", "oracle"):
        assert f"| {name} |" in report
        assert (out / "eval" / name / "records.jsonl").is_file()
    assert (out / "sr.png").stat().st_size > 5_000
    stages = sorted(p.stem for p in (out / "stages").glob("*.json"))
    assert len(stages) == 2 + 4 + 7 + 1
    command = json.loads((out / "stages" / "train-ours.json").read_text())["command"]
    assert command[:2] == ["collavn", "train"]


def test_a_second_run_does_no_stage_twice_and_other_arguments_are_refused(experiment,
                                                                          capsys):
    out, args = experiment
    before = {p.name: p.stat().st_mtime_ns for p in (out / "stages").glob("*.json")}
    capsys.readouterr()
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert printed.count("done before, skipped") == len(before)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "stages").glob("*.json")} == before
    with pytest.raises(CollavnError, match=r"other arguments.*episodes"):
        run_experiment(ExperimentConfig(out=out, episodes=2, budget_minutes=0.3,
                                        test_scenes=("procedural:1",)), write_report)


@pytest.mark.parametrize(("flag", "value", "message"), [
    ("--budget-minutes", "nan", "--budget-minutes must be a finite number > 0"),
    ("--eval-share", "1.5", "--eval-share must be < 1"),
    ("--episodes", "0", "--episodes must be an integer ≥ 1"),
])
def test_bad_experiment_arguments_are_one_line_errors(tmp_path, capsys, flag, value,
                                                      message):
    assert main(["experiment", "--out", str(tmp_path / "x"), flag, value]) == 2
    err = capsys.readouterr().err
    assert err.startswith("collavn: error:") and message in err
    assert not (tmp_path / "x").exists()  # refused before any work
