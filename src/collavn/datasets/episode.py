"""One navigation episode: where the agents start, where their goals are, how far.

An episode is fixed data, generated once (``generator.py``) and stored in episode
files (``storage.py``); the simulator turns it into an initial world state.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from collavn.errors import DatasetError, SceneError
from collavn.scenes.scene import Scene
from collavn.scenes.spec import SceneSpec
from collavn.scenes.splits import SPLITS
from collavn.tasks import TASKS

#: A difficulty bin's name (the keys of :data:`DIFFICULTY_BINS`).
Difficulty = Literal["easy", "medium", "hard"]
#: Geodesic start-to-goal bins ``[lo, hi)`` in metres; ``hard`` includes its upper end.
DIFFICULTY_BINS: dict[str, tuple[float, float]] = {
    "easy": (1.5, 3.0),
    "medium": (3.0, 5.0),
    "hard": (5.0, 10.0),
}


def check_task(task: str) -> str:
    """Return ``task`` if it is a known task setting, else raise :class:`DatasetError`."""
    if task not in TASKS:
        raise DatasetError(f"unknown task {task!r}; expected one of {', '.join(TASKS)}")
    return task


def check_split(split: str) -> str:
    """Return ``split`` if it is ``train``, ``val`` or ``test``, else raise."""
    if split not in SPLITS:
        raise DatasetError(f"unknown split {split!r}; expected one of {', '.join(SPLITS)}")
    return split


def check_difficulty(difficulty: str) -> str:
    """Return ``difficulty`` if it is ``easy``, ``medium`` or ``hard``, else raise."""
    if difficulty not in DIFFICULTY_BINS:
        raise DatasetError(f"unknown difficulty {difficulty!r}; expected one of "
                           f"{', '.join(DIFFICULTY_BINS)}")
    return difficulty


def in_bin(distance: np.ndarray, difficulty: str) -> np.ndarray:
    """Whether each geodesic distance lies in the bin of ``difficulty``.

    Raises:
        DatasetError: if ``difficulty`` is not ``easy``, ``medium`` or ``hard``.
    """
    lo, hi = DIFFICULTY_BINS[check_difficulty(difficulty)]
    d = np.asarray(distance)
    upper = d <= hi if difficulty == "hard" else d < hi
    return (d >= lo) & upper


@dataclass(frozen=True)
class SceneRef:
    """Which scene an episode belongs to, and how to load it again.

    Attributes:
        name: ``Scene.name``, e.g. ``procedural:3``.
        source: ``Scene.source``: ``procedural:SEED`` or the mesh path it came from.
        content_hash: ``Scene.content_hash``: SHA-256 of geometry and navigation.
        recorded_spec: ``Scene.spec``: the source and load options (up axis, scale,
            floor height) the scene was loaded with; ``None`` in files written
            before specs were recorded. Use :attr:`spec`.
    """

    name: str
    source: str
    content_hash: str
    recorded_spec: SceneSpec | None = None

    @classmethod
    def of(cls, scene: Scene) -> SceneRef:
        """The reference to ``scene``, with the spec it was loaded with."""
        return cls(scene.name, scene.source, scene.content_hash, scene.spec)

    @property
    def spec(self) -> SceneSpec:
        """What to pass to :func:`collavn.scenes.load_scene` to get the scene back.

        The recorded spec; for older files without one, the source with default
        load options (what those files were made with unless options were given).
        """
        return self.recorded_spec or SceneSpec.of(self.source)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON object (``spec`` only when recorded, so older files hash alike)."""
        out: dict[str, Any] = {"name": self.name, "source": self.source,
                               "content_hash": self.content_hash}
        if self.recorded_spec is not None:
            out["spec"] = self.recorded_spec.to_dict()
        return out

    @classmethod
    def from_json(cls, obj: dict[str, Any]) -> SceneRef:
        """Inverse of :meth:`to_json`.

        Raises:
            DatasetError: a missing field or an invalid recorded spec.
        """
        try:
            spec = obj.get("spec")
            return cls(name=str(obj["name"]), source=str(obj["source"]),
                       content_hash=str(obj["content_hash"]),
                       recorded_spec=None if spec is None else SceneSpec.from_dict(spec))
        except (KeyError, TypeError, AttributeError, SceneError) as e:
            raise DatasetError(f"malformed scene reference {obj!r}: {e}") from e


@dataclass(frozen=True, eq=False)
class Episode:
    """Start and goal poses of ``N`` agents in one scene.

    Positions are world ``(x, y)`` metres on the scene's floor, yaws radians from +x.
    Every agent's geodesic start-to-goal distance lies in the bin of ``difficulty``.

    Attributes:
        episode_id: Unique within a dataset, e.g. ``val/procedural:100/00012``.
        scene: The scene it was generated for.
        task: ``commongoal``, ``specificgoal`` or ``adhocoop``.
        difficulty: ``easy``, ``medium`` or ``hard``.
        start_positions: ``(N, 2)`` float64.
        start_yaws: ``(N,)`` float64.
        goal_positions: ``(G, 2)`` float64; ``G = 1`` for a shared goal, ``G = N``
            pairwise distinct goals for SpecificGoal.
        goal_yaws: ``(G,)`` float64: the goal image is a front view at this pose.
        goal_index: ``(N,)`` int64: agent ``n`` navigates to goal ``goal_index[n]``.
        start_distances: ``(N,)`` float64 geodesic start-to-goal distance per agent.
    """

    episode_id: str
    scene: SceneRef
    task: str
    difficulty: str
    start_positions: np.ndarray
    start_yaws: np.ndarray
    goal_positions: np.ndarray
    goal_yaws: np.ndarray
    goal_index: np.ndarray
    start_distances: np.ndarray

    def __post_init__(self) -> None:
        n, g = len(self.start_positions), len(self.goal_positions)
        checks = [
            (self.start_positions.shape == (n, 2) and n >= 1, "start_positions must be (N, 2)"),
            (self.start_yaws.shape == (n,), "start_yaws must be (N,)"),
            (self.goal_positions.shape == (g, 2) and g >= 1, "goal_positions must be (G, 2)"),
            (self.goal_yaws.shape == (g,), "goal_yaws must be (G,)"),
            (self.goal_index.shape == (n,), "goal_index must be (N,)"),
            (self.start_distances.shape == (n,), "start_distances must be (N,)"),
            (bool(np.all((self.goal_index >= 0) & (self.goal_index < g))),
             "goal_index points at a missing goal"),
        ]
        for ok, message in checks:
            if not ok:
                raise DatasetError(f"episode {self.episode_id!r}: {message}")

    @property
    def num_agents(self) -> int:
        """``N``, the number of agents."""
        return int(self.start_positions.shape[0])

    @property
    def agent_goals(self) -> np.ndarray:
        """``(N, 2)`` goal position of each agent."""
        return self.goal_positions[self.goal_index]

    @property
    def agent_goal_yaws(self) -> np.ndarray:
        """``(N,)`` goal yaw of each agent."""
        return self.goal_yaws[self.goal_index]

    def to_json(self) -> dict[str, Any]:
        """Plain JSON object (the scene and task are stored once per file)."""
        return {
            "episode_id": self.episode_id,
            "difficulty": self.difficulty,
            "start_positions": self.start_positions.tolist(),
            "start_yaws": self.start_yaws.tolist(),
            "goal_positions": self.goal_positions.tolist(),
            "goal_yaws": self.goal_yaws.tolist(),
            "goal_index": self.goal_index.tolist(),
            "start_distances": self.start_distances.tolist(),
        }

    @classmethod
    def from_json(cls, obj: dict[str, Any], scene: SceneRef, task: str) -> Episode:
        """Inverse of :meth:`to_json`.

        Raises:
            DatasetError: if a field is missing or malformed.
        """
        try:
            return cls(
                episode_id=str(obj["episode_id"]), scene=scene, task=task,
                difficulty=str(obj["difficulty"]),
                start_positions=np.asarray(obj["start_positions"], dtype=np.float64),
                start_yaws=np.asarray(obj["start_yaws"], dtype=np.float64),
                goal_positions=np.asarray(obj["goal_positions"], dtype=np.float64),
                goal_yaws=np.asarray(obj["goal_yaws"], dtype=np.float64),
                goal_index=np.asarray(obj["goal_index"], dtype=np.int64),
                start_distances=np.asarray(obj["start_distances"], dtype=np.float64),
            )
        except (KeyError, TypeError, ValueError) as e:
            raise DatasetError(f"malformed episode {obj.get('episode_id', '?')!r}: {e}") from e
