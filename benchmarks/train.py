"""Training throughput: agent-steps/s of collection alone and of the whole loop.

Runs the real trainer pieces (``collect_rollout`` then ``learn``: GAE + PPO epochs, or
the imitation step) for a few updates of each preset and prints agent-steps per second.
The ``paper`` preset (ResNet18 on 512×128) is slow on a CPU: by default it runs with
fewer envs and a short rollout; the rates are per agent-step, so they compare.
"collect" is acting in the envs (render + policy forward) without the map updates that
run between env steps; "map share" is the fraction of the loop spent training the map
(the paper's 10 updates of batch 64 per env step dominate a CPU run).

Usage: ``python benchmarks/train.py [--presets cpu paper] [--method ours] [--updates 2]
[--threads 2] [--paper-envs 2] [--paper-rollout 4]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import torch

from collavn.training.config import TrainConfig, preset_config
from collavn.training.distributed import DistInfo
from collavn.training.trainer import build_run, collect_rollout, learn, sync_point


def measure(cfg: TrainConfig, updates: int) -> tuple[float, float, float]:
    """(collection, whole loop) agent-steps/s and the map-training share of the loop.

    Map updates run inside collection (the paper trains the map every env step); their
    time is taken out of the collection rate and reported as a share of the loop.
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
    for _ in range(updates):
        t0 = time.perf_counter()
        rollout, _ = collect_rollout(run)
        t1 = time.perf_counter()
        learn(run, rollout)
        collect_s += t1 - t0
        total_s += time.perf_counter() - t0
    steps = updates * cfg.ppo.rollout_steps * cfg.run.num_envs * cfg.env.num_agents
    return steps / (collect_s - map_s), steps / total_s, map_s / total_s


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=["cpu", "paper"])
    parser.add_argument("--method", default="ours")
    parser.add_argument("--updates", type=int, default=2)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--paper-envs", type=int, default=2)
    parser.add_argument("--paper-rollout", type=int, default=4)
    parser.add_argument("--scenes", type=int, default=8, help="training scenes to load")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    from collavn.scenes.splits import scene_specs

    scenes = tuple(scene_specs("train")[: args.scenes])
    print(f"method {args.method}, {args.threads} torch threads, {args.updates} updates")
    print(f"{'preset':<8}{'envs':>6}{'agents':>8}{'T':>5}{'collect st/s':>15}{'loop st/s':>12}"
          f"{'map share':>11}")
    for preset in args.presets:
        cfg = preset_config(preset, method=args.method).with_run(scenes=scenes, progress=False)
        cfg = cfg.with_env(render_threads=args.threads)
        if preset == "paper":
            cfg = replace(cfg, ppo=replace(cfg.ppo, rollout_steps=args.paper_rollout)
                          ).with_run(num_envs=args.paper_envs)
        collect, loop, share = measure(cfg, args.updates)
        print(f"{preset:<8}{cfg.run.num_envs:>6}{cfg.env.num_agents:>8}"
              f"{cfg.ppo.rollout_steps:>5}"
              f"{collect:>15.1f}{loop:>12.1f}{share:>10.0%}")


if __name__ == "__main__":
    main()
