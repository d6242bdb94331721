"""Run a policy over fixed episodes and collect per-agent records and trajectories."""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from collavn.datasets.episode import Episode
from collavn.envs.config import EnvConfig
from collavn.envs.vector import VectorEnv
from collavn.metrics import SIGHT_DISTANCE, AgentRecord
from collavn.policies.base import CommStats, Policy
from collavn.policies.oracle import in_sight
from collavn.scenes.scene import Scene
from collavn.scenes.spec import SceneSpec


@dataclass
class Trajectory:
    """Where the agents of one episode went (for pictures).

    Attributes:
        episode_id: The episode.
        scene: How to load its scene again (source and load options).
        poses: ``(T + 1, N, 3)`` world poses from the start to the end.
        goals: ``(N, 2)`` goal position of each agent.
        goal_yaws: ``(N,)`` goal view direction of each agent.
        success: ``(N,)`` bool.
    """

    episode_id: str
    scene: SceneSpec
    poses: np.ndarray
    goals: np.ndarray
    goal_yaws: np.ndarray
    success: np.ndarray

    def to_json(self) -> dict[str, Any]:
        """JSON object."""
        return {"episode_id": self.episode_id, "scene": self.scene.to_dict(),
                "poses": np.round(self.poses, 4).tolist(), "goals": self.goals.tolist(),
                "goal_yaws": self.goal_yaws.tolist(), "success": self.success.tolist()}

    @classmethod
    def from_json(cls, obj: dict[str, Any]) -> Trajectory:
        """Inverse of :meth:`to_json`."""
        scene = obj["scene"]  # a bare source string in files written before specs
        spec = SceneSpec(scene) if isinstance(scene, str) else SceneSpec.from_dict(scene)
        return cls(obj["episode_id"], spec, np.asarray(obj["poses"], float),
                   np.asarray(obj["goals"], float), np.asarray(obj["goal_yaws"], float),
                   np.asarray(obj["success"], bool))


@dataclass
class EvaluationResult:
    """Records of every agent of every episode, some trajectories, the communication."""

    records: list[AgentRecord] = field(default_factory=list)
    trajectories: list[Trajectory] = field(default_factory=list)
    communication: CommStats = field(default_factory=CommStats)

    def add(self, other: EvaluationResult) -> None:
        """Append ``other``'s records and trajectories and add its communication."""
        self.records += other.records
        self.trajectories += other.trajectories
        self.communication.add(other.communication)


def first_sightings(scene: Scene, poses: np.ndarray, goals: np.ndarray, steps: Sequence[int],
                    sight: float = SIGHT_DISTANCE) -> list[int]:
    """Per agent, the first step its goal was in sight (``-1``: never).

    Args:
        scene: The episode's scene.
        poses: ``(T + 1, N, 3)`` poses, row ``k`` after step ``k`` (row 0: the start).
        goals: ``(N, 2)`` goal positions.
        steps: Per agent, the steps it ran (later rows are not looked at: a finished
            agent no longer searches).
        sight: :func:`~collavn.policies.oracle.in_sight`'s distance (the seeker's).
    """
    return [next((k for k in range(steps[n] + 1) if in_sight(scene, poses[k, n, :2], goal,
                                                             sight)), -1)
            for n, goal in enumerate(np.asarray(goals, dtype=np.float64))]


def evaluate(policy: Policy, scene: Scene, episodes: Sequence[Episode], config: EnvConfig,
             num_envs: int = 4, seed: int = 0, keep_trajectories: int = 0,
             on_episode: Callable[[int], None] | None = None) -> EvaluationResult:
    """Run ``policy`` on each episode of one scene exactly once.

    Args:
        policy: Acts for ``(E, N)`` agents (see :mod:`collavn.policies`).
        scene: The scene the episodes belong to.
        episodes: Episodes with ``config.num_agents`` agents each.
        config: Sensors and rules (``num_agents`` may differ from training: Ad-hoCoop).
        num_envs: Envs stepped together.
        seed: Seeds the env (odometry noise) — episodes themselves are fixed.
        keep_trajectories: Keep the paths of the first this-many episodes.
        on_episode: Called with 1 after each finished episode (progress bars).
    """
    episodes = list(episodes)
    num_envs = max(1, min(num_envs, len(episodes)))
    env = VectorEnv([scene], num_envs, config, episodes=[episodes], seed=seed)
    obs, _ = env.reset(seed=seed)
    state = policy.initial_state(num_envs, config.num_agents)
    group = env.groups[0]
    world = group.world
    wanted = {ep.episode_id for ep in episodes[:keep_trajectories]}
    paths: list[list[np.ndarray]] = [[world.poses()[e]] for e in range(num_envs)]
    done: dict[str, list[AgentRecord]] = {}
    trajectories: list[Trajectory] = []
    while len(done) < len(episodes):
        before = list(group.episodes)
        actions, state = policy.act(obs, state)
        obs, _, _, _, info = env.step(actions)
        ended = info["episode_done"]
        for e in range(num_envs):
            ep = before[e]
            assert ep is not None
            paths[e].append(info["final_poses"][e])
        fresh = {r.episode_id for r in info["episode_records"]} - set(done)
        for rec in info["episode_records"]:  # envs cycle: a repeat run is not recorded
            if rec.episode_id in fresh:
                done.setdefault(rec.episode_id, []).append(rec)
        for k in np.flatnonzero(ended):
            e = int(k)
            ep = before[e]
            assert ep is not None
            if ep.episode_id in fresh:
                recs = sorted(done[ep.episode_id], key=lambda r: r.agent)
                seen = first_sightings(scene, np.stack(paths[e]), ep.agent_goals,
                                       [r.steps for r in recs])
                done[ep.episode_id] = [replace(r, sighted_step=s)
                                       for r, s in zip(recs, seen, strict=True)]
            if ep.episode_id in fresh and ep.episode_id in wanted:
                success = np.array([r.success for r in sorted(done[ep.episode_id],
                                                              key=lambda r: r.agent)])
                spec = scene.spec or SceneSpec(scene.source)
                trajectories.append(Trajectory(ep.episode_id, spec,
                                               np.stack(paths[e]), ep.agent_goals,
                                               ep.agent_goal_yaws, success))
            paths[e] = [world.poses()[e]]
            if on_episode is not None and ep.episode_id in fresh:
                on_episode(1)
    records = [r for ep in episodes for r in sorted(done[ep.episode_id], key=lambda r: r.agent)]
    return EvaluationResult(records, trajectories, policy.communication())


def write_records(path: str | Path, records: Sequence[AgentRecord]) -> Path:
    """One JSON object per agent record, one per line."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("".join(json.dumps(asdict(r), sort_keys=True) + "\n" for r in records))
    return path


def read_records(path: str | Path) -> list[AgentRecord]:
    """Inverse of :func:`write_records`."""
    lines = Path(path).read_text().splitlines()
    return [AgentRecord(**json.loads(line)) for line in lines if line.strip()]


def write_trajectories(path: str | Path, trajectories: Sequence[Trajectory]) -> Path:
    """One trajectory per line (JSON Lines)."""
    path = Path(path)
    path.write_text("".join(json.dumps(t.to_json()) + "\n" for t in trajectories))
    return path


def read_trajectories(path: str | Path) -> list[Trajectory]:
    """Inverse of :func:`write_trajectories`."""
    lines = Path(path).read_text().splitlines()
    return [Trajectory.from_json(json.loads(line)) for line in lines if line.strip()]
