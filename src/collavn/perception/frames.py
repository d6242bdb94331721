"""Labelled frames for pretraining: panoramas and goal images rendered in scenes.

Every (panorama, goal of the same scene) pair is labelled by :mod:`.labels`.

Per scene: ``goals_per_scene`` goals with informative front views (the episode
generator's goals), ``frames_per_scene`` agent poses within ``near_distance`` of one of
them (random yaw, density ∝ 1/distance) and the full ``(frames × goals)`` label tables.
Batches pair a panorama with its own goal or another of its scene, and rotate (roll) and
mirror panorama, goal and labels together: a rolled panorama *is* the view after turning
in place, so the augmentation is exact.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from collavn.datasets.generator import SamplingConfig, sample_episodes
from collavn.envs.config import EnvConfig
from collavn.envs.sensors import Sensors
from collavn.perception.config import PerceptionConfig
from collavn.perception.labels import (
    free_space,
    geodesic_distances,
    goal_columns,
    path_columns,
)
from collavn.scenes.scene import Scene


@dataclass(frozen=True)
class FrameSet:
    """Frames of several scenes; ``P`` panoramas, ``G`` goals per scene.

    Attributes:
        panoramas: ``(P, 3, H, W)`` uint8.
        goals: ``(S·G, 3, Hg, Wg)`` uint8 goal images.
        goal_index: ``(P, G)`` index into ``goals`` of each goal of the panorama's scene.
        own: ``(P,)`` which of its scene's goals the panorama was sampled near.
        distance: ``(P, G)`` geodesic metres (``inf``: unreachable).
        goal_column: ``(P, G)`` straight-line bearing as a panorama column.
        path_column: ``(P, G)`` shortest-path bearing as a column (NaN: unreachable).
        free: ``(P, W)`` free metres along every column.
        depths: ``(P, H, W)`` float16 metres of each panorama (``None``: not rendered;
            the frame perception reads them iff ``ModelConfig.frame_depth``).
    """

    panoramas: np.ndarray
    goals: np.ndarray
    goal_index: np.ndarray
    own: np.ndarray
    distance: np.ndarray
    goal_column: np.ndarray
    path_column: np.ndarray
    free: np.ndarray
    depths: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.panoramas)


def _poses_near(scene: Scene, goals: np.ndarray, count: int, near: float,
                rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``count`` positions spread over the goals (each within ``near`` m of its goal)."""
    nav = scene.nav
    positions, owner = [], []
    per_goal = np.diff(np.linspace(0, count, len(goals) + 1).astype(int))
    for g, (goal, k) in enumerate(zip(goals, per_goal, strict=True)):
        grid = scene.geodesic_field(goal).grid
        cells = np.flatnonzero(np.isfinite(grid.ravel()) & (grid.ravel() <= near)
                               & nav.navigable.ravel())
        weight = 1.0 / np.maximum(grid.ravel()[cells], 0.5)
        pick = rng.choice(cells, k, p=weight / weight.sum())
        r, c = np.divmod(pick, nav.shape[1])
        jitter = rng.uniform(-0.4, 0.4, (k, 2)) * nav.resolution
        positions.append(nav.cell_centers(r, c) + jitter)
        owner += [g] * k
    return np.concatenate(positions), np.asarray(owner, dtype=np.int64)


def render_frames(scenes: Sequence[Scene], env: EnvConfig, cfg: PerceptionConfig,
                  frames_per_scene: int, rng: np.random.Generator,
                  on_scene: Callable[[int], None] | None = None,
                  depth: bool = False) -> FrameSet:
    """Render and label ``frames_per_scene`` panoramas and the goals of every scene.

    ``depth``: keep each panorama's depth too (``FrameSet.depths``).
    """
    parts: list[dict[str, np.ndarray]] = []
    goal_images: list[np.ndarray] = []
    offset = 0
    g_count = cfg.goals_per_scene
    for scene in scenes:
        episodes = sample_episodes(scene, "commongoal", 1, "easy", g_count, rng,
                                   SamplingConfig(episodes_per_goal=1))
        goals = np.stack([ep.goal_positions[0] for ep in episodes])
        goal_yaws = np.array([ep.goal_yaws[0] for ep in episodes])
        pos, own = _poses_near(scene, goals, frames_per_scene, cfg.near_distance, rng)
        yaws = rng.uniform(-np.pi, np.pi, len(pos))
        sensors = Sensors(scene, env)
        try:
            views = sensors.panoramas(np.concatenate([pos, yaws[:, None]], 1)[:, None])
            goal_poses = np.concatenate([goals, goal_yaws[:, None]], 1)[:, None]
            goal_images.append(sensors.goal_images(goal_poses)[:, 0])
        finally:
            sensors.renderer.close()
        w = env.panorama_width
        fields = [scene.geodesic_field(g) for g in goals]
        parts.append({
            "panoramas": views.rgb[:, 0],
            **({"depths": views.depth[:, 0].astype(np.float16)} if depth else {}),
            "goal_index": np.broadcast_to(offset + np.arange(g_count), (len(pos), g_count)),
            "own": own,
            "distance": np.stack([geodesic_distances(f, pos) for f in fields], 1),
            "goal_column": np.stack([goal_columns(pos, yaws, g, w) for g in goals], 1),
            "path_column": np.stack([path_columns(f, pos, yaws, w) for f in fields], 1),
            "free": free_space(scene.nav, pos, yaws, w, cfg.max_free),
        })
        offset += g_count
        if on_scene is not None:
            on_scene(1)
    joined = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return FrameSet(goals=np.concatenate(goal_images), **joined)


def sample_batch(frames: FrameSet, size: int, cfg: PerceptionConfig,
                 rng: np.random.Generator, augment: bool = True) -> dict[str, np.ndarray]:
    """A batch of labelled pairs (rolled and mirrored when ``augment``).

    Returns:
        ``panorama (B, 3, H, W)``, ``goal (B, 3, Hg, Wg)`` uint8; ``distance (B,)``,
        ``goal_column (B,)``, ``path_column (B,)`` and ``free (B, W)`` float; with
        ``frames.depths`` also ``depth (B, H, W)`` float32, turned with the panorama.
    """
    p = rng.integers(0, len(frames), size)
    g_count = frames.goal_index.shape[1]
    j = np.where(rng.random(size) < cfg.own_goal_fraction, frames.own[p],
                 rng.integers(0, g_count, size))
    pano, goal = frames.panoramas[p], frames.goals[frames.goal_index[p, j]]
    free = frames.free[p]
    depth = None if frames.depths is None else frames.depths[p].astype(np.float32)
    cols = {k: getattr(frames, k)[p, j].astype(np.float64)
            for k in ("goal_column", "path_column")}
    w = pano.shape[-1]
    if augment:
        # Roll right by k columns (= turn left in place): column c → c + k. Mirrored as
        # well: panorama column j shows old column k − j, so c → k − c.
        shift = rng.integers(0, w, size)
        flip = (rng.random(size) < 0.5) if cfg.mirror else np.zeros(size, bool)
        index = np.where(flip[:, None], shift[:, None] - np.arange(w)[None, :],
                         np.arange(w)[None, :] - shift[:, None]) % w
        goal = np.where(flip[:, None, None, None], goal[..., ::-1], goal)
        pano = np.take_along_axis(pano, index[:, None, None, :], axis=-1)
        free = np.take_along_axis(free, index, axis=-1)
        if depth is not None:
            depth = np.take_along_axis(depth, index[:, None, :], axis=-1)
        for k, c in cols.items():
            cols[k] = np.mod(np.where(flip, shift - c, c + shift), w)
    return {"panorama": np.ascontiguousarray(pano), "goal": np.ascontiguousarray(goal),
            "distance": frames.distance[p, j], "free": free, **cols,
            **({} if depth is None else {"depth": np.ascontiguousarray(depth)})}
