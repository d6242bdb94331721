"""Evaluation throughput of a trained model: fixed blocks of envs vs one env at a time.

Runs :func:`collavn.evaluation.runner.evaluate` with a :class:`CheckpointPolicy` on the
same episodes twice in one process — ``block_envs=1`` (the reference: one env per
forward pass) and the default block — and prints episodes/s, agent-steps/s, the ratio,
and whether the records agree exactly between ``--num-envs`` values (they must, for the
blocked policy). Without ``--checkpoint`` an untrained ``cpu``-preset model is used
(the speed does not depend on the weights).

Usage: ``python benchmarks/evaluate.py [--checkpoint FILE] [--episodes 16]
[--num-envs 8] [--scene procedural:1000] [--threads 1]``.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import torch

from collavn.datasets.generator import sample_episodes
from collavn.envs import EnvConfig
from collavn.evaluation.runner import evaluate
from collavn.models import ActorCritic, ModelConfig
from collavn.policies.adapter import env_overrides
from collavn.policies.checkpoint import BLOCK_ENVS, CheckpointPolicy, load_policy
from collavn.scenes import load_scene
from collavn.threads import apply_threads


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--checkpoint", default="", help="a training checkpoint.pt")
    parser.add_argument("--episodes", type=int, default=16)
    parser.add_argument("--num-envs", type=int, default=8)
    parser.add_argument("--scene", default="procedural:1000")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    apply_threads(args.threads)
    if args.checkpoint:
        policy, overrides = load_policy(args.checkpoint)
        model = policy.model
    else:
        torch.manual_seed(0)
        cfg = ModelConfig.cpu()
        model = ActorCritic(cfg)
        overrides = env_overrides(cfg)
    env = replace(EnvConfig(task="commongoal", num_agents=2), **overrides)
    scene = load_scene(args.scene)
    episodes = sample_episodes(scene, "commongoal", 2, "easy", args.episodes,
                               np.random.default_rng(0))
    results = {}
    for label, block in (("one env at a time", 1), (f"blocks of {BLOCK_ENVS}", BLOCK_ENVS)):
        policy = CheckpointPolicy(model, block_envs=block)
        t0 = time.perf_counter()
        result = evaluate(policy, scene, episodes, env, num_envs=args.num_envs)
        seconds = time.perf_counter() - t0
        steps = policy.communication().agent_steps
        results[block] = (seconds, result.records)
        print(f"{label:18s}: {seconds:6.1f} s, {len(episodes) / seconds:5.2f} episodes/s, "
              f"{steps / seconds:6.1f} agent-steps/s")
    print(f"ratio: {results[1][0] / results[BLOCK_ENVS][0]:.2f}×")
    other = evaluate(CheckpointPolicy(model), scene, episodes, env,
                     num_envs=max(1, args.num_envs // 2 - 1)).records
    print(f"blocked records identical for --num-envs {args.num_envs} and "
          f"{max(1, args.num_envs // 2 - 1)}: {other == results[BLOCK_ENVS][1]}")


if __name__ == "__main__":
    main()
