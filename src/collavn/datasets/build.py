"""Generate a dataset directory: scenes × splits → episode files + index, with progress."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from pathlib import Path

from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

import collavn
from collavn.datasets.episode import SceneRef, check_split
from collavn.datasets.generator import (
    Preset,
    SamplingConfig,
    agents_for_split,
    episode_rng,
    generate_split,
    get_preset,
)
from collavn.datasets.storage import (
    EpisodeFile,
    episode_path,
    group_name,
    save_episode_file,
    write_index,
)
from collavn.errors import DatasetError
from collavn.scenes.scene import Scene


def generate_dataset(out: str | Path, scenes: Sequence[Scene], task: str, agents: int,
                     split: str, preset: str | Preset = "small", seed: int = 0,
                     eval_agents: int | None = None,
                     config: SamplingConfig | None = None,
                     progress: bool = True) -> list[Path]:
    """Generate and write the episode files of one task setting and split.

    Each (scene, split) gets its own random stream derived from ``seed``
    (:func:`~collavn.datasets.generator.episode_rng`), so files do not depend on
    which other scenes were generated with them and the same seed gives
    byte-identical files. ``out/index.json`` is rewritten afterwards.

    Args:
        out: Dataset directory (created if needed).
        scenes: Scenes of ``split``; names must be distinct.
        task: ``commongoal``, ``specificgoal`` or ``adhocoop``.
        agents: ``N`` (Ad-hoCoop: the training ``N``).
        split: ``train``, ``val`` or ``test``.
        preset: ``paper`` or ``small`` episode counts, or a custom :class:`Preset`.
        seed: Master seed.
        eval_agents: Ad-hoCoop only: ``N'`` of val/test (default 2→3, 3→2).
        config: Sampling constraints and budgets (default :class:`SamplingConfig`).
        progress: Show a rich progress bar.

    Returns:
        The written files, in scene order.

    Raises:
        DatasetError: for invalid arguments or a scene that cannot yield the
            requested episodes (nothing is written for that scene).
    """
    counts = preset if isinstance(preset, Preset) else get_preset(preset)
    config = config or SamplingConfig()
    check_split(split)
    n = agents_for_split(task, agents, eval_agents, split)
    if task == "adhocoop":
        eval_agents = agents_for_split(task, agents, eval_agents, "val")
    names = [s.name for s in scenes]
    if len(set(names)) != len(names):
        raise DatasetError(f"scene names must be distinct, got {names}")
    group = group_name(task, agents, eval_agents)
    meta = {"seed": seed, "preset": counts.name, "train_agents": agents,
            "eval_agents": eval_agents if task == "adhocoop" else agents,
            "sampling": dataclasses.asdict(config), "collavn_version": collavn.__version__}
    written = []
    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
               TimeElapsedColumn())
    with Progress(*columns, disable=not progress) as bar:
        for scene in scenes:
            total = sum(counts.counts(split).values())
            job = bar.add_task(f"{group} {split} {scene.name}", total=total)
            rng = episode_rng(seed, task, n, split, scene.name)
            episodes = generate_split(scene, task, n, split, counts, rng, config,
                                      on_progress=functools.partial(bar.advance, job))
            path = episode_path(out, group, split, scene.name)
            save_episode_file(path, EpisodeFile(
                task=task, num_agents=n, split=split,
                scene=SceneRef.of(scene),
                generator=meta, episodes=tuple(episodes)))
            written.append(path)
    write_index(out)
    return written
