"""Training throughput: agent-steps/s of collection alone and of the whole loop.

Runs the real trainer pieces (``collect_rollout`` then ``learn``: GAE + PPO epochs, or
the imitation step) for a few updates of each preset and method and prints agent-steps
per second. The ``paper`` preset (ResNet18 on 512×128) is slow on a CPU: by default it
runs with fewer envs and a short rollout; the rates are per agent-step, so they compare.
"collect" is acting in the envs (render + policy forward) without the map updates;
"map share" is the fraction of the loop spent training the map.

``--encoder DIR/encoder.pt`` trains on a frozen pretrained encoder (its features stored
in the rollout, as ``collavn train --encoder``). ``--contended`` measures every row twice,
alone and with a second process spinning on one core, and prints the ratio (a run should
keep at least half its speed when another one shares a 2-core machine).

Usage: ``python benchmarks/train.py [--presets cpu paper] [--methods no-com ours]
[--updates 2] [--torch-threads 0] [--render-threads 1] [--encoder FILE] [--contended]
[--profile 20]``.
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import pstats
import subprocess
import sys
import time
from dataclasses import replace

import torch

from collavn.training.config import TrainConfig
from collavn.training.distributed import DistInfo
from collavn.training.presets import preset_config
from collavn.training.trainer import build_run, collect_rollout, learn, sync_point


def measure(cfg: TrainConfig, updates: int, profile: int = 0
            ) -> tuple[float, float, float]:
    """(collection, whole loop) agent-steps/s and the map-training share of the loop.

    Map updates run inside collection (the paper trains the map every env step); their
    time is taken out of the collection rate and reported as a share of the loop.
    ``profile`` > 0 runs collection and learning under ``cProfile`` and prints that many
    top entries of each (by own time; the rates then include the profiler's overhead).
    """
    run = build_run(cfg, DistInfo(), torch.device(cfg.run.device))
    sync_point(run)
    rollout, _ = collect_rollout(run)  # warm-up
    learn(run, rollout)
    map_s = 0.0
    train_maps = run.maps.train

    def timed_map_train(*args: object, **kwargs: object) -> object:
        nonlocal map_s
        t = time.perf_counter()
        try:
            return train_maps(*args, **kwargs)
        finally:
            map_s += time.perf_counter() - t

    run.maps.train = timed_map_train
    collect_s = total_s = 0.0
    profilers = (cProfile.Profile(), cProfile.Profile()) if profile else None
    for _ in range(updates):
        t0 = time.perf_counter()
        with profilers[0] if profilers else contextlib.nullcontext():
            rollout, _ = collect_rollout(run)
        t1 = time.perf_counter()
        with profilers[1] if profilers else contextlib.nullcontext():
            learn(run, rollout)
        collect_s += t1 - t0
        total_s += time.perf_counter() - t0
    if profilers:
        for name, profiler in zip(("collection", "learning"), profilers, strict=True):
            print(f"--- {cfg.method}: {name}, {updates} updates, top {profile} by own time")
            pstats.Stats(profiler).sort_stats("tottime").print_stats(profile)
    steps = updates * cfg.ppo.rollout_steps * cfg.run.num_envs * cfg.env.num_agents
    return steps / (collect_s - map_s), steps / total_s, map_s / total_s


def busy_process() -> subprocess.Popen[bytes]:
    """A second process spinning on one core until it is killed."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def row(preset: str, method: str, args: argparse.Namespace) -> TrainConfig:
    """The benchmark's config of one preset and method."""
    from collavn.scenes.splits import scene_specs

    scenes = tuple(scene_specs("train")[: args.scenes])
    cfg = preset_config(preset, method=method).with_run(
        scenes=scenes, progress=False, torch_threads=args.torch_threads, encoder=args.encoder)
    cfg = cfg.with_env(render_threads=args.render_threads)
    if preset == "paper":
        cfg = replace(cfg, ppo=replace(cfg.ppo, rollout_steps=args.paper_rollout)
                      ).with_run(num_envs=args.paper_envs)
    return cfg


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["cpu", "paper"])
    parser.add_argument("--methods", nargs="+", default=["no-com", "ours"])
    parser.add_argument("--updates", type=int, default=2)
    parser.add_argument("--torch-threads", type=int, default=0, help="0 = automatic")
    parser.add_argument("--render-threads", type=int, default=1)
    parser.add_argument("--encoder", default="", help="a pretrained encoder.pt (frozen)")
    parser.add_argument("--contended", action="store_true",
                        help="also measure with a second process busy on one core")
    parser.add_argument("--paper-envs", type=int, default=2)
    parser.add_argument("--paper-rollout", type=int, default=4)
    parser.add_argument("--scenes", type=int, default=8, help="training scenes to load")
    parser.add_argument("--profile", type=int, default=0, metavar="N",
                        help="print the top N cProfile entries of collection and learning")
    args = parser.parse_args()
    print(f"{args.updates} updates, torch threads {args.torch_threads or 'auto'}, "
          f"render threads {args.render_threads}, encoder {args.encoder or 'none (pixels)'}")
    print(f"{'preset':<8}{'method':<8}{'envs':>5}{'T':>4}{'collect st/s':>14}"
          f"{'loop st/s':>11}{'map share':>11}" + (f"{'contended':>11}{'ratio':>7}"
                                                   if args.contended else ""))
    for preset in args.presets:
        for method in args.methods:
            cfg = row(preset, method, args)
            collect, loop, share = measure(cfg, args.updates, args.profile)
            line = (f"{preset:<8}{method:<8}{cfg.run.num_envs:>5}{cfg.ppo.rollout_steps:>4}"
                    f"{collect:>14.1f}{loop:>11.1f}{share:>10.0%}")
            if args.contended:
                busy = busy_process()
                try:
                    _, contended, _ = measure(cfg, args.updates)
                finally:
                    busy.kill()
                    busy.wait()
                line += f"{contended:>11.1f}{contended / loop:>7.2f}"
            print(line, flush=True)


if __name__ == "__main__":
    main()
