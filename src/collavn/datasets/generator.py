"""Sample episodes: goals first, then many starts at once from the goal's geodesic field.

For each goal (or set of goals for SpecificGoal) the geodesic field is computed once
(the scene caches it); the cells whose distance lies in the difficulty bin are
listed, and a batch of candidate start configurations is drawn from them at once:
one random cell per agent, jittered inside the cell, kept when every agent's exact
geodesic distance is in the bin and the agents stand apart. A goal yields up to
``episodes_per_goal`` episodes (each with its own goal view direction), so
generation costs one fast-marching run per few episodes.

Sampling is rejection sampling with a bounded budget of goal tries: a scene that
cannot yield the requested episodes raises :class:`DatasetError` saying how many
were found, instead of looping forever or silently returning fewer.

Goal views: a goal image must be informative (not a wall 10 cm away). Of 32 random
yaws we keep those whose straight line of sight stays in free space
(``NavGrid.free``: floor and nothing in the robot's height band) for at least
``min_view_depth`` = 1.5 m, and pick among them; a goal with no such yaw is rejected.
"""

from __future__ import annotations

import dataclasses
import hashlib
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from collavn.datasets.episode import (
    DIFFICULTY_BINS,
    Episode,
    SceneRef,
    check_difficulty,
    check_split,
    check_task,
    in_bin,
)
from collavn.errors import DatasetError
from collavn.scenes.navigation import GeodesicField, NavGrid
from collavn.scenes.scene import Scene
from collavn.scenes.splits import SPLITS

#: Positions, yaws and distances are rounded to this many decimals (0.1 mm) so that
#: stored episodes reproduce exactly after a JSON round trip.
DECIMALS = 4


@dataclass(frozen=True)
class Preset:
    """How many episodes to generate per scene.

    Attributes:
        name: ``paper`` or ``small``.
        train: Train episodes per scene, spread evenly over the difficulties.
        val: Val episodes per scene *per difficulty*.
        test: Test episodes per scene *per difficulty*.
    """

    name: str
    train: int
    val: int
    test: int

    def counts(self, split: str) -> dict[str, int]:
        """Episodes per difficulty for one scene of ``split``."""
        if check_split(split) != "train":
            return dict.fromkeys(DIFFICULTY_BINS, getattr(self, split))
        q, r = divmod(self.train, len(DIFFICULTY_BINS))
        return {d: q + (i < r) for i, d in enumerate(DIFFICULTY_BINS)}


#: The paper's counts (5,000 train per scene; 500 val / 1,000 test per scene and
#: difficulty) and a small one for CI and smoke tests.
PRESETS = {
    "paper": Preset("paper", train=5000, val=500, test=1000),
    "small": Preset("small", train=20, val=10, test=10),
}


def get_preset(name: str) -> Preset:
    """Look up a preset by name; raise :class:`DatasetError` if unknown."""
    if name not in PRESETS:
        raise DatasetError(f"unknown preset {name!r}; expected one of {', '.join(PRESETS)}")
    return PRESETS[name]


@dataclass(frozen=True)
class SamplingConfig:
    """Constraints and budgets of episode sampling.

    Attributes:
        min_separation: Minimum distance between agents' start positions in metres;
            ``None`` = two body radii of the scene's nav config + 0.1 m margin.
        min_goal_separation: Minimum distance between the goals of a SpecificGoal
            episode (equal to the success radius: goals are pairwise distinct).
        min_view_depth: Free space required straight ahead of the goal pose.
        episodes_per_goal: Episodes drawn from one goal (set) before a new goal.
        draws_per_goal: Candidate start configurations drawn per goal at once.
        max_goal_tries: Goal tries allowed on top of 4 per needed goal.
    """

    min_separation: float | None = None
    min_goal_separation: float = 1.0
    min_view_depth: float = 1.5
    episodes_per_goal: int = 4
    draws_per_goal: int = 64
    max_goal_tries: int = 200


def sample_episodes(scene: Scene, task: str, num_agents: int, difficulty: str, count: int,
                    rng: np.random.Generator, config: SamplingConfig = SamplingConfig(),
                    on_progress: Callable[[int], None] | None = None) -> list[Episode]:
    """Draw ``count`` episodes of one difficulty in ``scene``.

    Args:
        scene: Where to sample; its geodesic fields are computed and cached.
        task: ``commongoal`` / ``adhocoop`` (one shared goal) or ``specificgoal``
            (``num_agents`` pairwise distinct goals).
        num_agents: ``N ≥ 1``.
        difficulty: ``easy``, ``medium`` or ``hard``: every agent's geodesic
            start-to-goal distance lies in that bin.
        count: How many episodes.
        rng: The only source of randomness.
        config: Constraints and budgets.
        on_progress: Called with the number of new episodes after each goal.

    Returns:
        ``count`` episodes with ids ``{difficulty}-{k}`` (callers renumber them).

    Raises:
        DatasetError: for an unknown task or difficulty, ``num_agents < 1``, or if
            the try budget runs out (the message says how many were found).
    """
    check_task(task)
    check_difficulty(difficulty)
    if num_agents < 1:
        raise DatasetError(f"num_agents must be ≥ 1, got {num_agents}")
    nav = scene.nav
    sep = (2 * nav.config.agent_radius + 0.1 if config.min_separation is None
           else config.min_separation)
    ref = SceneRef.of(scene)
    num_goals = num_agents if task == "specificgoal" else 1
    goal_index = np.arange(num_agents) % num_goals
    cells = np.flatnonzero(nav.navigable)
    episodes: list[Episode] = []
    budget = config.max_goal_tries + 4 * math.ceil(count / config.episodes_per_goal)
    for _ in range(budget):
        if len(episodes) >= count:
            break
        goals = _sample_goals(nav, cells, num_goals, rng, config.min_goal_separation)
        views = None if goals is None else [_open_yaws(nav, g, rng, config) for g in goals]
        if goals is None or views is None or any(len(v) == 0 for v in views):
            continue
        fields = [scene.geodesic_field(goals[i]) for i in goal_index]
        want = min(config.episodes_per_goal, count - len(episodes))
        starts, dists = _draw_starts(nav, fields, difficulty, want, sep, rng,
                                     config.draws_per_goal)
        for pos, dist in zip(starts, dists, strict=True):
            episodes.append(Episode(
                episode_id=f"{difficulty}-{len(episodes)}", scene=ref, task=task,
                difficulty=difficulty, start_positions=pos,
                start_yaws=np.round(rng.uniform(-np.pi, np.pi, num_agents), DECIMALS),
                goal_positions=goals,
                goal_yaws=np.array([rng.choice(v) for v in views]),
                goal_index=goal_index.astype(np.int64), start_distances=dist))
        if on_progress is not None and len(starts):
            on_progress(len(starts))
    if len(episodes) < count:
        lo, hi = DIFFICULTY_BINS[difficulty]
        raise DatasetError(
            f"scene {scene.name!r}: found only {len(episodes)} of {count} {difficulty} "
            f"{task} episodes with {num_agents} agents after {budget} goal tries "
            f"(every agent's geodesic start-to-goal distance in [{lo}, {hi}"
            f"{']' if difficulty == 'hard' else ')'} m); the scene's "
            f"navigable area may be too small for this difficulty")
    return episodes


def generate_split(scene: Scene, task: str, num_agents: int, split: str, preset: Preset,
                   rng: np.random.Generator, config: SamplingConfig = SamplingConfig(),
                   on_progress: Callable[[int], None] | None = None) -> list[Episode]:
    """All episodes of one scene for one split, numbered ``{split}/{scene}/{k:05d}``.

    Val/test episodes come grouped by difficulty (easy, medium, hard); train
    episodes are spread evenly over the difficulties and shuffled.

    Raises:
        DatasetError: see :func:`sample_episodes`; also for an unknown split.
    """
    episodes: list[Episode] = []
    for difficulty, count in preset.counts(split).items():
        episodes += sample_episodes(scene, task, num_agents, difficulty, count, rng,
                                    config, on_progress)
    if split == "train":
        episodes = [episodes[i] for i in rng.permutation(len(episodes))]
    return [dataclasses.replace(e, episode_id=f"{split}/{scene.name}/{k:05d}")
            for k, e in enumerate(episodes)]


def episode_rng(seed: int, task: str, num_agents: int, split: str,
                scene_name: str) -> np.random.Generator:
    """The generator of one (task, N, split, scene) file, independent of the others.

    CommonGoal and Ad-hoCoop share streams (both sample one shared goal), so an
    Ad-hoCoop 2→3 dataset trains on the CommonGoal N=2 episodes and is evaluated on
    the CommonGoal N=3 ones, as in the paper.
    """
    shared = 0 if check_task(task) in ("commongoal", "adhocoop") else 1
    name_key = int.from_bytes(hashlib.sha256(scene_name.encode()).digest()[:8], "little")
    key = (shared, num_agents, SPLITS.index(check_split(split)), name_key)
    return np.random.default_rng(np.random.SeedSequence(seed, spawn_key=key))


# ----------------------------------------------------------------- internals
def _cell_points(nav: NavGrid, flat: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Random points inside the given flat cell indices, rounded to ``DECIMALS``."""
    r, c = np.divmod(flat, nav.shape[1])
    jitter = rng.uniform(-0.45, 0.45, (*np.shape(flat), 2)) * nav.resolution
    return np.round(nav.cell_centers(r, c) + jitter, DECIMALS)


def _sample_goals(nav: NavGrid, cells: np.ndarray, num_goals: int, rng: np.random.Generator,
                  min_separation: float) -> np.ndarray | None:
    """``(G, 2)`` goals in one component, pairwise ≥ ``min_separation``; None if failed."""
    first = _cell_points(nav, rng.choice(cells, 1), rng)
    if num_goals == 1:
        return first
    label = int(nav.component_at(first[0]))
    same = cells[nav.components.ravel()[cells] == label]
    goals = [first[0]]
    for p in _cell_points(nav, rng.choice(same, 16 * num_goals), rng):
        if min(np.linalg.norm(p - g) for g in goals) >= min_separation:
            goals.append(p)
            if len(goals) == num_goals:
                return np.stack(goals)
    return None


def _open_yaws(nav: NavGrid, goal: np.ndarray, rng: np.random.Generator,
               config: SamplingConfig, candidates: int = 32) -> np.ndarray:
    """Random yaws from ``goal`` with free line of sight ≥ ``min_view_depth``."""
    yaws = np.round(rng.uniform(-np.pi, np.pi, candidates), DECIMALS)
    # a fifth of a cell: a ray that only clips a blocked cell's corner is caught too
    steps = np.arange(0.0, config.min_view_depth + 1e-9, 0.2 * nav.resolution)
    direction = np.stack([np.cos(yaws), np.sin(yaws)], axis=-1)
    points = goal + steps[None, :, None] * direction[:, None, :]
    return yaws[nav.lookup(nav.free, points, outside=False).all(axis=1)]


def _draw_starts(nav: NavGrid, fields: list[GeodesicField], difficulty: str, want: int,
                 separation: float, rng: np.random.Generator,
                 draws: int) -> tuple[np.ndarray, np.ndarray]:
    """Up to ``want`` start sets: ``(K, N, 2)`` positions and ``(K, N)`` distances.

    Agent ``n`` starts in a cell whose distance in ``fields[n]`` is within one cell
    of the bin; exact distances of the jittered points decide.
    """
    lo, hi = DIFFICULTY_BINS[difficulty]
    n = len(fields)
    points = np.empty((draws, n, 2))
    dists = np.empty((draws, n))
    cell_lists: dict[int, np.ndarray] = {}
    for a, field in enumerate(fields):
        key = id(field)
        if key not in cell_lists:
            grid = field.grid.ravel()
            cell_lists[key] = np.flatnonzero((grid >= lo - nav.resolution)
                                             & (grid <= hi + nav.resolution))
        if len(cell_lists[key]) == 0:
            return np.empty((0, n, 2)), np.empty((0, n))
        points[:, a] = _cell_points(nav, rng.choice(cell_lists[key], draws), rng)
        dists[:, a] = np.round(field.distance(points[:, a]), DECIMALS)
    ok = in_bin(dists, difficulty).all(axis=1)
    if n > 1:
        gaps = np.linalg.norm(points[:, :, None] - points[:, None, :], axis=-1)
        gaps[:, np.arange(n), np.arange(n)] = np.inf
        ok &= gaps.min(axis=(1, 2)) >= separation
    keep = np.flatnonzero(ok)[:want]
    return points[keep], dists[keep]


def agents_for_split(task: str, agents: int, eval_agents: int | None, split: str) -> int:
    """``N`` of one split: Ad-hoCoop trains with ``agents`` and evaluates with ``eval_agents``.

    Raises:
        DatasetError: if the pair is invalid for ``task``.
    """
    check_task(task)
    if agents < 1:
        raise DatasetError(f"--agents must be ≥ 1, got {agents}")
    if task != "adhocoop":
        if eval_agents not in (None, agents):
            raise DatasetError(f"{task} evaluates with the training number of agents; "
                               f"only adhocoop takes a different --eval-agents")
        return agents
    if eval_agents is None:
        eval_agents = ADHOC_EVAL_AGENTS.get(agents)
        if eval_agents is None:
            raise DatasetError(f"adhocoop with {agents} agents needs --eval-agents "
                               f"(the paper's pairs are 2→3 and 3→2)")
    if eval_agents == agents or eval_agents < 1:
        raise DatasetError(f"adhocoop needs --eval-agents ≥ 1 different from --agents "
                           f"({agents}), got {eval_agents}")
    return agents if check_split(split) == "train" else eval_agents


#: The paper's Ad-hoCoop pairs: trained with N, evaluated with N'.
ADHOC_EVAL_AGENTS = {2: 3, 3: 2}
