"""`collavn …` — the command line: one module per command; no library module imports it.

A command is a dataclass (fields documented, turned into ``--help`` by tyro) with a
``run()`` method, or a ``main(args, prog)`` function when it parses a config tree
itself (``train``). This file only maps command words to them and imports them
lazily, so ``collavn --help`` is fast.
"""

from __future__ import annotations

import importlib
import sys

from collavn.configs import use_tyro
from collavn.errors import CollavnError, Interrupted

#: command words → (module, class or function, one line). Add a line to add a command.
COMMANDS: dict[tuple[str, ...], tuple[str, str, str]] = {
    ("demo",): ("collavn.cli.demo", "Demo",
                "Episodes on a procedural scene, oracle vs random, table and pictures."),
    ("scene", "info"): ("collavn.cli.scene", "SceneInfo",
                        "Describe a scene: size, navigable area, components; draw its map."),
    ("dataset", "generate"): ("collavn.cli.dataset", "DatasetGenerate",
                              "Generate episode files of one task setting and split."),
    ("dataset", "info"): ("collavn.cli.dataset", "DatasetInfo",
                          "Summarise an episode dataset: counts per difficulty, histograms."),
    ("render",): ("collavn.cli.render", "RenderCommand",
                  "Render a panorama (or goal view) at a pose, with a depth picture."),
    ("evaluate",): ("collavn.cli.evaluate", "Evaluate",
                    "Score a policy or checkpoint on a dataset: records and tables."),
    ("compare",): ("collavn.cli.compare", "Compare",
                   "Paired bootstrap differences (SR, SPL, DTS) between evaluations."),
    ("viz",): ("collavn.cli.viz", "Viz",
               "Trajectory maps and an episode GIF from an evaluation's output."),
    ("pretrain",): ("collavn.cli.pretrain", "main",
                    "Pretrain the frame perception on simulator labels → encoder.pt."),
    ("train",): ("collavn.cli.train", "main",
                 "Train ours / no-mem / no-com (PPO) or il; checkpoints, TensorBoard, resume."),
    ("average",): ("collavn.cli.average", "Average",
                   "Average the weights of a run's checkpoints (snapshots) into one policy."),
    ("pick",): ("collavn.cli.pick", "Pick",
                "Keep the snapshot of a run that scores best on training-scene episodes."),
    ("experiment",): ("collavn.cli.experiment", "Experiment",
                      "The paper's table end to end for a budget: train, evaluate, report."),
}


def _usage(only: list[tuple[str, ...]] | None = None) -> str:
    lines = ["usage: collavn COMMAND [options]   (collavn COMMAND --help for details)", "",
             "commands:"]
    for words, (_, _, doc) in COMMANDS.items():
        if only is not None and words not in only:
            continue
        lines.append(f"  {' '.join(words):<20} {doc}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``collavn`` console script."""
    args = list(sys.argv[1:] if argv is None else argv)
    for words, (module, name, _) in sorted(COMMANDS.items(), key=lambda kv: -len(kv[0])):
        if tuple(args[: len(words)]) == words:
            target = getattr(importlib.import_module(module), name)
            prog, rest = "collavn " + " ".join(words), args[len(words):]
            try:
                if isinstance(target, type):
                    return int(use_tyro().cli(target, args=rest, prog=prog).run() or 0)
                return int(target(rest, prog) or 0)
            except CollavnError as e:
                print(f"collavn: error: {e}", file=sys.stderr)
                return 2
            except OSError as e:  # disk full, permissions, … outside our own checks
                print(f"collavn: error: {e.strerror or e}"
                      f"{f': {e.filename}' if e.filename else ''}", file=sys.stderr)
                return 2
            except Interrupted as e:
                print(f"collavn: {e}", file=sys.stderr)
                return 128 + e.signum
            except KeyboardInterrupt:
                print("collavn: interrupted", file=sys.stderr)
                return 130
    group = [w for w in COMMANDS if len(w) > 1 and args[:1] == [w[0]]]
    if group:  # e.g. ``collavn scene --help``: the subcommands of that word
        asked = args[1:2] in (["-h"], ["--help"])
        print(_usage(group), file=sys.stdout if asked else sys.stderr)
        return 0 if asked else 2
    print(_usage(), file=sys.stderr if args and args[0] not in ("-h", "--help") else sys.stdout)
    return 0 if not args or args[0] in ("-h", "--help") else 2


if __name__ == "__main__":
    raise SystemExit(main())
