"""Parameter counts and CPU forward time per agent-step of the agent models.

Usage: ``python benchmarks/models.py [--threads 2] [--repeats 5]``.
"""

from __future__ import annotations

import argparse
import time

import torch

from collavn.models import ActorCritic, CommConfig, ModelConfig


def count(module: torch.nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())


def observations(cfg: ModelConfig, e: int, n: int) -> dict[str, torch.Tensor]:
    return dict(
        panorama=torch.randint(0, 256, (e, n, *cfg.panorama_shape), dtype=torch.uint8),
        goal=torch.randint(0, 256, (e, n, *cfg.goal_shape), dtype=torch.uint8),
        pose_delta=torch.randn(e, n, 3) * 0.3, active=torch.ones(e, n, dtype=torch.bool),
        free_space=torch.rand(e, n, cfg.free_space_input) * 4.0)


def time_steps(model: ActorCritic, cfg: ModelConfig, e: int, n: int, repeats: int) -> float:
    """Median seconds per ``act`` call over ``repeats`` consecutive steps (memory grows)."""
    obs = observations(cfg, e, n)
    state = model.initial_state(e, n)
    start = torch.ones(e, n, dtype=torch.bool)
    out = model.act(obs, state, start)  # warm-up
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = model.act(obs, out.state, torch.zeros_like(start))
        times.append(time.perf_counter() - t0)
    return sorted(times)[len(times) // 2]


def report(name: str, cfg: ModelConfig, e: int, n: int, repeats: int) -> None:
    torch.manual_seed(0)
    model = ActorCritic(cfg).eval()
    tower = model.towers[0]
    parts = {"panorama enc": tower.panorama_encoder, "goal enc": tower.goal_encoder,
             "map builder": tower.map_builder, "map enc": tower.map_encoder,
             "goal matching": tower.goal_matcher, "readout": tower.readout,
             "comm": tower.comm,
             "cores+heads": [tower.actor_core, tower.critic_core, tower.actor_mean,
                             tower.critic_value]}
    sizes = []
    for label, mod in parts.items():
        mods = mod if isinstance(mod, list) else [mod]
        sizes.append(f"{label} {sum(count(m) for m in mods if m is not None) / 1e6:.2f}M")
    print(f"[{name}] params {count(model) / 1e6:.2f}M = " + ", ".join(sizes))
    for variant in ("none", "handshake", "memory"):
        vcfg = ModelConfig(**{**cfg.__dict__, "comm": CommConfig(
            **{**cfg.comm.__dict__, "variant": variant})})
        vmodel = ActorCritic(vcfg).eval()
        sec = time_steps(vmodel, vcfg, e, n, repeats)
        print(f"[{name}] {variant:9s} E={e} N={n}: {sec * 1e3:7.1f} ms/step, "
              f"{sec / (e * n) * 1e3:6.2f} ms per agent-step")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    print(f"torch {torch.__version__}, {args.threads} threads, eval mode, no grad")
    report("cpu", ModelConfig.cpu(), e=8, n=3, repeats=args.repeats)
    report("paper", ModelConfig.paper(), e=2, n=3, repeats=args.repeats)


if __name__ == "__main__":
    main()
