"""Episode files: one gzip-compressed JSON per (task, N, split, scene), plus an index.

In the spirit of habitat-lab's episode files, with an identity check on both ends::

    {"schema_version": 1, "task": "commongoal", "num_agents": 2, "split": "val",
     "scene": {"name": "procedural:100", "source": "procedural:100", "content_hash": …},
     "generator": {"seed": 0, "preset": "small", …},
     "episodes": [{"episode_id": …, "difficulty": "easy", "start_positions": …}, …],
     "content_hash": sha256 of the canonical JSON of everything above}

Layout: ``DIR/<task>_n<N>/<split>/<scene>.json.gz`` (Ad-hoCoop: ``adhocoop_n2to3``)
and ``DIR/index.json`` listing every file with its counts and hash. Files are
written atomically (temporary file + ``os.replace``) and byte-identically for the
same content (canonical JSON, gzip ``mtime=0``).
"""

from __future__ import annotations

import gzip
import hashlib
import json
import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from collavn.datasets.episode import (
    DIFFICULTY_BINS,
    Episode,
    SceneRef,
    check_split,
    check_task,
    in_bin,
)
from collavn.errors import DatasetError
from collavn.files import atomic_write
from collavn.scenes.scene import Scene

#: Bumped whenever the layout of an episode file changes.
SCHEMA_VERSION = 1
INDEX_NAME = "index.json"


@dataclass(frozen=True, eq=False)
class EpisodeFile:
    """The content of one episode file.

    Attributes:
        task: ``commongoal``, ``specificgoal`` or ``adhocoop``.
        num_agents: ``N`` of every episode in the file.
        split: ``train``, ``val`` or ``test``.
        scene: Identity of the scene the episodes were generated for.
        generator: How they were generated (seed, preset, agents, …): provenance.
        episodes: The episodes, in file order.
    """

    task: str
    num_agents: int
    split: str
    scene: SceneRef
    generator: dict[str, Any]
    episodes: tuple[Episode, ...] = field(default=())

    def to_json(self) -> dict[str, Any]:
        """The file's JSON object without its ``content_hash``."""
        return {"schema_version": SCHEMA_VERSION, "task": self.task,
                "num_agents": self.num_agents, "split": self.split,
                "scene": self.scene.to_json(), "generator": self.generator,
                "episodes": [e.to_json() for e in self.episodes]}

    @property
    def content_hash(self) -> str:
        """SHA-256 of the canonical JSON of :meth:`to_json`."""
        return _hash(self.to_json())

    def check_scene(self, scene: Scene, path: str | Path = "episode file") -> None:
        """Refuse another scene than the episodes', or start distances it disagrees with.

        The scene to check is usually ``load_scene(content.scene.spec)``: the source
        and load options this file recorded.

        Raises:
            DatasetError: naming both scenes, both hashes and both load specs; or the
                first episode whose geodesic start-to-goal distances in ``scene`` differ
                from the stored ones (which :func:`load_episode_file` checked against
                the episode's difficulty bin).
        """
        if scene.content_hash == self.scene.content_hash:
            for e in self.episodes:
                d = np.array([scene.geodesic_distance(s, g)
                              for s, g in zip(e.start_positions, e.agent_goals, strict=True)])
                if not np.allclose(d, e.start_distances, rtol=0.0, atol=1e-3):
                    raise DatasetError(
                        f"{path}: episode {e.episode_id}: stored start distances "
                        f"{_metres(e.start_distances)} differ from those recomputed in its "
                        f"scene, {_metres(d)}; regenerate the episodes")
            return
        given = (scene.spec.describe() if scene.spec
                 else f"{scene.source or scene.name} with unknown options")
        raise DatasetError(
            f"{path} was generated for scene {self.scene.name!r} "
            f"(sha256 {self.scene.content_hash[:12]}…, loaded as {self._recorded_load()}) "
            f"but was given scene {scene.name!r} (sha256 {scene.content_hash[:12]}…, "
            f"loaded as {given}): load the scene with the recorded spec "
            f"(load_scene(content.scene.spec); on the command line the same --up-axis, "
            f"--scale and --floor-height) or regenerate the episodes")

    def _recorded_load(self) -> str:
        if self.scene.recorded_spec is None:
            return f"{self.scene.source} with options not recorded (an older file)"
        return self.scene.recorded_spec.describe()


def group_name(task: str, num_agents: int, eval_agents: int | None = None) -> str:
    """Directory of one task setting: ``commongoal_n2``, ``adhocoop_n2to3``."""
    check_task(task)
    if eval_agents is not None and eval_agents != num_agents:
        return f"{task}_n{num_agents}to{eval_agents}"
    return f"{task}_n{num_agents}"


def episode_path(root: str | Path, group: str, split: str, scene_name: str) -> Path:
    """``root/<group>/<split>/<scene>.json.gz``; the scene name made file-safe."""
    safe = re.sub(r"[^A-Za-z0-9._-]+", "_", scene_name).strip("._") or "scene"
    return Path(root) / group / check_split(split) / f"{safe}.json.gz"


def save_episode_file(path: str | Path, content: EpisodeFile) -> str:
    """Write ``content`` to ``path`` atomically; returns its content hash."""
    doc = content.to_json()
    digest = _hash(doc)
    doc["content_hash"] = digest
    data = gzip.compress(_canonical(doc), compresslevel=6, mtime=0)
    atomic_write(Path(path), data)
    return digest


def load_episode_file(path: str | Path, scene: Scene | None = None) -> EpisodeFile:
    """Read and verify an episode file.

    Args:
        path: A ``.json.gz`` file written by :func:`save_episode_file`.
        scene: If given, the episodes must have been generated for this scene.

    Raises:
        DatasetError: if the file is unreadable, has another schema version, was
            edited (content hash mismatch) or does not match ``scene``.
    """
    path = Path(path)
    try:
        doc = json.loads(gzip.decompress(path.read_bytes()))
    except (OSError, EOFError, ValueError) as e:
        raise DatasetError(f"cannot read episode file {path}: {e}") from e
    if not isinstance(doc, dict) or doc.get("schema_version") != SCHEMA_VERSION:
        found = doc.get("schema_version") if isinstance(doc, dict) else None
        raise DatasetError(f"{path}: episode schema version {found!r}, "
                           f"expected {SCHEMA_VERSION}")
    stored = doc.pop("content_hash", None)
    if stored != _hash(doc):
        raise DatasetError(f"{path} was modified after it was written: its content hash "
                           f"does not match; regenerate it instead of editing it")
    try:
        ref = SceneRef.from_json(doc["scene"])
        task = check_task(doc["task"])
        content = EpisodeFile(
            task=task, num_agents=int(doc["num_agents"]), split=check_split(doc["split"]),
            scene=ref, generator=dict(doc["generator"]),
            episodes=tuple(Episode.from_json(e, ref, task) for e in doc["episodes"]))
    except (KeyError, TypeError) as e:
        raise DatasetError(f"{path}: malformed episode file: {e}") from e
    for episode in content.episodes:
        check_bin(episode, episode.start_distances, path, "stored")
    if scene is not None:
        content.check_scene(scene, path)
    return content


def check_bin(episode: Episode, distances: np.ndarray, path: str | Path, how: str) -> None:
    """Refuse an episode labelled with a difficulty its start distances do not have.

    Raises:
        DatasetError: naming the episode, its label, the distances and the bin.
    """
    try:
        ok = bool(in_bin(distances, episode.difficulty).all())
    except DatasetError as e:
        raise DatasetError(f"{path}: episode {episode.episode_id}: {e}") from e
    if not ok:
        lo, hi = DIFFICULTY_BINS[episode.difficulty]
        raise DatasetError(
            f"{path}: episode {episode.episode_id} is labelled {episode.difficulty} "
            f"([{lo:g}, {hi:g}) m) but its agents start {_metres(distances)} from their "
            f"goals ({how}); the file was relabelled or is damaged: regenerate it")


def _metres(d: np.ndarray) -> str:
    return ", ".join(f"{v:.2f}" for v in np.asarray(d, dtype=float)) + " m"


def write_index(root: str | Path) -> Path:
    """Scan ``root`` for episode files and (re)write ``root/index.json``."""
    root = Path(root)
    entries = []
    for path in sorted(root.glob("*/*/*.json.gz")):
        content = load_episode_file(path)
        difficulties: dict[str, int] = {}
        for e in content.episodes:
            difficulties[e.difficulty] = difficulties.get(e.difficulty, 0) + 1
        entries.append({"path": path.relative_to(root).as_posix(),
                        "group": path.parent.parent.name, "task": content.task,
                        "num_agents": content.num_agents, "split": content.split,
                        "scene": content.scene.name, "episodes": len(content.episodes),
                        "difficulties": difficulties, "content_hash": content.content_hash})
    index = {"schema_version": SCHEMA_VERSION, "files": entries}
    out = root / INDEX_NAME
    atomic_write(out, json.dumps(index, indent=1, sort_keys=True).encode() + b"\n")
    return out


@dataclass(frozen=True, eq=False)
class Dataset:
    """All episode files of a dataset directory.

    Attributes:
        root: The directory holding ``index.json``.
        files: ``{relative path: content}`` in index order.
    """

    root: Path
    files: dict[str, EpisodeFile]

    @classmethod
    def load(cls, root: str | Path, group: str | None = None, split: str | None = None,
             scenes: Mapping[str, Scene] | None = None) -> Dataset:
        """Load the files listed in ``root/index.json``, optionally filtered.

        Args:
            root: Dataset directory.
            group: Only this task setting, e.g. ``commongoal_n2``.
            split: Only this split.
            scenes: ``{scene name: Scene}``; files of these scenes are checked
                against them.

        Raises:
            DatasetError: if the index is missing or a file is invalid, edited, or
                does not match its index entry or its scene.
        """
        root = Path(root)
        try:
            index = json.loads((root / INDEX_NAME).read_text())
        except (OSError, ValueError) as e:
            raise DatasetError(f"{root} is not an episode dataset (no readable "
                               f"{INDEX_NAME}: {e})") from e
        files = {}
        for entry in index.get("files", []):
            if (group and entry["group"] != group) or (split and entry["split"] != split):
                continue
            scene = (scenes or {}).get(entry["scene"])
            content = load_episode_file(root / entry["path"], scene)
            if content.content_hash != entry["content_hash"]:
                raise DatasetError(f"{root / entry['path']} does not match its entry in "
                                   f"{root / INDEX_NAME}; rerun the generator")
            files[entry["path"]] = content
        return cls(root=root, files=files)

    def episodes(self, difficulty: str | None = None) -> Iterator[Episode]:
        """Every episode in file order, optionally of one difficulty only."""
        for content in self.files.values():
            for e in content.episodes:
                if difficulty is None or e.difficulty == difficulty:
                    yield e

    def __len__(self) -> int:
        return sum(len(c.episodes) for c in self.files.values())


def _canonical(obj: Any) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), allow_nan=False).encode()


def _hash(obj: Any) -> str:
    return hashlib.sha256(_canonical(obj)).hexdigest()
