"""Environment throughput: env-steps/s, agent-steps/s, rendering share, memory.

Targets (issue, 2-core CPU): ≥ 60 env-steps/s for CommonGoal N=2 at 512×128
(≥ 120 agent-steps/s), ≥ 800 agent-steps/s at 128×32, rendering ≥ 80 % of step
time; 16 envs of N=4 under 2 GB RSS.

    python benchmarks/env.py
"""

from __future__ import annotations

import resource
import time

import numpy as np

from collavn.envs import EnvConfig, VectorEnv
from collavn.envs.sensors import Sensors
from collavn.scenes import load_scene


def measure(scene, agents: int, width: int, envs: int, steps: int = 40) -> None:
    config = EnvConfig(num_agents=agents, panorama_width=width, panorama_height=width // 4,
                       goal_size=min(128, width // 4))
    env = VectorEnv([scene], envs, config, seed=0)
    env.reset(seed=0)
    render_time = [0.0]
    original = Sensors.panoramas

    def timed(self, poses):
        start = time.perf_counter()
        out = original(self, poses)
        render_time[0] += time.perf_counter() - start
        return out

    Sensors.panoramas = timed  # count the panorama rendering inside step()
    rng = np.random.default_rng(0)
    actions = [rng.uniform(-1, 1, (envs, agents, 2)) for _ in range(steps)]
    start = time.perf_counter()
    for a in actions:
        env.step(a)
    total = time.perf_counter() - start
    Sensors.panoramas = original
    rate = steps * envs / total
    print(f"N={agents} {width}x{width // 4} E={envs}: {rate:7.1f} env-steps/s  "
          f"{rate * agents:7.1f} agent-steps/s  rendering {100 * render_time[0] / total:4.1f} %"
          " of step time")


def main() -> None:
    scene = load_scene("procedural:0")
    for agents in (2, 4):
        for width in (512, 128):
            measure(scene, agents, width, envs=8)
    env = VectorEnv([scene], 16, EnvConfig(num_agents=4), seed=0)
    env.reset(seed=0)
    for _ in range(5):
        env.step(np.zeros((16, 4, 2)))
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"peak RSS after 16 envs × 4 agents at 512x128 (and the runs above): {rss:.0f} MB "
          "(target < 2048)")


if __name__ == "__main__":
    main()
