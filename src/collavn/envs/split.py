"""A vector env in parts, each part stepped on a worker thread: env and policy overlap.

Collecting a rollout alternates two kinds of work that wait on each other: the policy
forward (torch) needs the observations, the env step (render, physics, rewards) needs
the actions. With all envs in one batch they run one after the other and one of the
two cores idles. :class:`SplitVectorEnv` cuts the ``E`` envs into parts (two by
default) that the caller drives in turn::

    for each part p:  wait for p's observations → policy forward on p → step_async(p)

so while the worker thread steps part A, the caller runs the policy on part B, then A's
forward runs while the worker steps B. Torch ops, Embree ray casts and the Numba
shading all release the GIL, so the two threads use two cores.

Each part is a :class:`~collavn.envs.vector.VectorEnv` of its own envs and scenes (env
``i`` of the whole is in ``scenes[i % len(scenes)]``, as in one ``VectorEnv``), seeded
with a seed derived from the part's index: the run is deterministic, but its episodes
differ from those of a single ``VectorEnv`` with the same seed. One part is exactly a
``VectorEnv`` (same seed, same episodes), stepped on the calling thread.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from itertools import pairwise
from typing import Any

import numpy as np

from collavn.envs.config import EnvConfig
from collavn.envs.vector import VectorEnv, episode_seed
from collavn.errors import CollavnError
from collavn.scenes import Scene

Step = tuple[dict[str, Any], np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]


def part_bounds(num_envs: int, parts: int) -> list[slice]:
    """``parts`` consecutive env ranges of (nearly) equal size covering ``num_envs``."""
    if not 1 <= parts <= num_envs:
        raise CollavnError(f"cannot cut {num_envs} envs into {parts} parts")
    edges = [round(p * num_envs / parts) for p in range(parts + 1)]
    return [slice(a, b) for a, b in pairwise(edges)]


def join_obs(parts: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """Observations (or per-env info arrays) of consecutive parts, joined along envs."""
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


class SplitVectorEnv:
    """``E`` envs in consecutive parts stepped on one worker thread; see the module doc.

    Args:
        scenes: Env ``i`` lives in ``scenes[i % len(scenes)]``.
        num_envs: ``E``.
        config: Sensors, task and episode settings.
        seed: Seeds the parts (part ``p`` of several gets a seed derived from it).
        parts: How many parts (at most ``num_envs``); 1 steps on the calling thread.
    """

    def __init__(self, scenes: Sequence[Scene], num_envs: int, config: EnvConfig,
                 seed: int | None = None, parts: int = 2) -> None:
        if not scenes:
            raise CollavnError("SplitVectorEnv needs at least one scene")
        self.bounds = part_bounds(num_envs, parts)
        self.num_envs, self.num_agents = num_envs, config.num_agents
        self.parts: list[VectorEnv] = []
        self._scene_offset: list[int] = []
        offset = 0
        for b in self.bounds:
            size = b.stop - b.start
            # local env j of the part is in own[j % len(own)] = scenes[(start + j) % L]
            own = [scenes[(b.start + j) % len(scenes)] for j in range(min(len(scenes), size))]
            self.parts.append(VectorEnv(own, size, config,
                                        seed=self._part_seed(seed, len(self.parts))))
            self._scene_offset.append(offset)
            offset += len(own)
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="collavn-env") if parts > 1 \
            else None
        self._pending: list[Future[Step] | None] = [None] * parts

    def _part_seed(self, seed: int | None, p: int) -> int | None:
        if seed is None or len(self.bounds) == 1:
            return seed
        return episode_seed(seed, f"part {p}")

    @property
    def scenes(self) -> list[Scene]:
        """Every part's scenes in order, indexed by ``obs["scene_index"]``."""
        return [s for part in self.parts for s in part.scenes]

    def reset(self, seed: int | None = None) -> tuple[dict[str, Any], dict[str, Any]]:
        """New episodes in every env; ``(obs, info)`` of all envs."""
        self._drain()
        out = [self._indexed(p, part.reset(None if seed is None else
                                           self._part_seed(seed, p))[0])
               for p, part in enumerate(self.parts)]
        return join_obs(out), {"episode_done": np.zeros(self.num_envs, bool)}

    def part_obs(self, obs: dict[str, Any], p: int) -> dict[str, Any]:
        """Part ``p``'s slice of observations of all envs."""
        return {k: v[self.bounds[p]] for k, v in obs.items()}

    def step_async(self, p: int, actions: np.ndarray) -> None:
        """Start stepping part ``p`` with its ``(E_p, N, 2)`` actions."""
        if self._pending[p] is not None:
            raise CollavnError(f"part {p} is already stepping: call step_wait({p}) first")
        part = self.parts[p]
        if self._pool is None:
            done: Future[Step] = Future()
            try:
                done.set_result(part.step(actions))
            except Exception as e:  # re-raised by step_wait, as from the thread
                done.set_exception(e)
            self._pending[p] = done
        else:
            self._pending[p] = self._pool.submit(part.step, np.array(actions))

    def step_wait(self, p: int) -> Step:
        """Part ``p``'s ``(obs, reward, terminated, truncated, info)`` (as ``VectorEnv.step``)."""
        pending = self._pending[p]
        if pending is None:
            raise CollavnError(f"part {p} is not stepping: call step_async({p}, …) first")
        self._pending[p] = None
        obs, reward, terminated, truncated, info = pending.result()
        return self._indexed(p, obs), reward, terminated, truncated, info

    def step(self, actions: np.ndarray) -> Step:
        """Step every part with ``(E, N, 2)`` actions; results of all envs."""
        for p, b in enumerate(self.bounds):
            self.step_async(p, actions[b])
        return join_steps([self.step_wait(p) for p in range(len(self.parts))])

    def close(self) -> None:
        """Finish pending steps and stop the worker thread."""
        self._drain()
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None

    def _drain(self) -> None:
        for p, pending in enumerate(self._pending):
            if pending is not None:
                self._pending[p] = None
                pending.exception()  # wait; an error of a discarded step is dropped

    def _indexed(self, p: int, obs: dict[str, Any]) -> dict[str, Any]:
        if "scene_index" in obs and self._scene_offset[p]:
            obs = dict(obs, scene_index=obs["scene_index"] + self._scene_offset[p])
        return obs


def join_steps(steps: Sequence[Step]) -> Step:
    """The step results of consecutive parts as one step of all their envs."""
    obs = join_obs([s[0] for s in steps])
    reward, terminated, truncated = (np.concatenate([s[k] for s in steps]) for k in (1, 2, 3))
    info = join_obs([{k: v for k, v in s[4].items() if k != "episode_records"}
                     for s in steps])
    info["episode_records"] = [r for s in steps for r in s[4]["episode_records"]]
    return obs, reward, terminated, truncated, info
