"""Episode generation invariants, episode files (determinism, integrity), the CLI."""

from __future__ import annotations

import gzip
import json
import os
from pathlib import Path

import numpy as np
import pytest
import tyro
from hypothesis import given, settings
from hypothesis import strategies as st

from collavn.cli.dataset import DatasetGenerate, DatasetInfo
from collavn.datasets.build import generate_dataset
from collavn.datasets.episode import DIFFICULTY_BINS, Episode, in_bin
from collavn.datasets.generator import (
    Preset,
    SamplingConfig,
    agents_for_split,
    episode_rng,
    generate_split,
    get_preset,
    sample_episodes,
)
from collavn.datasets.storage import (
    Dataset,
    EpisodeFile,
    load_episode_file,
    save_episode_file,
)
from collavn.errors import DatasetError
from collavn.scenes.builder import SceneBuilder, flat_texture
from collavn.scenes.scene import Scene

PRESET = Preset("test", train=6, val=4, test=4)


@pytest.fixture(scope="module")
def tiny_room() -> Scene:
    """A 2.5 × 2.5 m room: easy episodes only just fit, hard ones never do."""
    b = SceneBuilder(texture_size=8)
    m = b.material("w", flat_texture((200, 200, 200), 8))
    b.add_box((0, 0, -0.1), (2.5, 2.5, 0), m)
    for lo, hi in (((0, 0, 0), (2.5, 0.1, 2.5)), ((0, 2.4, 0), (2.5, 2.5, 2.5)),
                   ((0, 0, 0), (0.1, 2.5, 2.5)), ((2.4, 0, 0), (2.5, 2.5, 2.5))):
        b.add_box(lo, hi, m)
    return b.build("tiny")


def check_episode(scene: Scene, e: Episode) -> None:
    """Every invariant an episode must satisfy, checked independently of the generator."""
    nav = scene.nav
    n = e.num_agents
    assert in_bin(e.start_distances, e.difficulty).all()
    assert nav.is_navigable(e.start_positions).all()
    assert nav.is_navigable(e.goal_positions).all()
    goal_comp = nav.component_at(e.agent_goals)
    assert (nav.component_at(e.start_positions) == goal_comp).all() and (goal_comp > 0).all()
    for a in range(n):
        d = scene.geodesic_distance(e.start_positions[a], e.agent_goals[a])
        assert d == pytest.approx(e.start_distances[a], abs=1e-3)
    gaps = np.linalg.norm(e.start_positions[:, None] - e.start_positions[None], axis=-1)
    assert (gaps[~np.eye(n, dtype=bool)] >= 2 * nav.config.agent_radius + 0.1 - 1e-9).all()
    # Goal views look down ≥ 1.5 m of free space (checked at 2 cm steps).
    steps = np.arange(0, 1.5, 0.02)
    for g, yaw in zip(e.goal_positions, e.goal_yaws, strict=True):
        ray = g + steps[:, None] * np.array([np.cos(yaw), np.sin(yaw)])
        assert nav.lookup(nav.free, ray, outside=False).all()


@pytest.mark.parametrize("task", ["commongoal", "specificgoal"])
@pytest.mark.parametrize("n", [2, 3, 4])
def test_episodes_respect_bins_and_constraints(door_scene, task, n):
    rng = episode_rng(0, task, n, "val", door_scene.name)
    episodes = generate_split(door_scene, task, n, "val", PRESET, rng)
    assert [e.difficulty for e in episodes] == [d for d in DIFFICULTY_BINS for _ in range(4)]
    assert len({e.episode_id for e in episodes}) == len(episodes)
    for e in episodes:
        assert e.num_agents == n and e.task == task
        check_episode(door_scene, e)
        if task == "specificgoal":
            assert len(e.goal_positions) == n and list(e.goal_index) == list(range(n))
            gaps = np.linalg.norm(e.goal_positions[:, None] - e.goal_positions[None], axis=-1)
            assert (gaps[~np.eye(n, dtype=bool)] >= 1.0).all()  # pairwise distinct
        else:
            assert len(e.goal_positions) == 1 and not e.goal_index.any()


@settings(max_examples=15, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 4),
       difficulty=st.sampled_from(list(DIFFICULTY_BINS)))
def test_invariants_hold_for_any_seed(door_scene, seed, n, difficulty):
    rng = np.random.default_rng(seed)
    for e in sample_episodes(door_scene, "specificgoal", n, difficulty, 2, rng):
        check_episode(door_scene, e)


def test_train_split_mixes_difficulties(open_room):
    episodes = generate_split(open_room, "commongoal", 2, "train", PRESET,
                              episode_rng(0, "commongoal", 2, "train", open_room.name))
    assert len(episodes) == 6
    assert sorted(e.difficulty for e in episodes) == ["easy"] * 2 + ["hard"] * 2 + ["medium"] * 2
    assert episodes[0].episode_id == "train/open-room/00000"


def test_impossible_request_is_a_clear_error(tiny_room):
    rng = np.random.default_rng(0)
    message = r"scene 'tiny': found only 0 of 5 hard .*\[5\.0, 10\.0\] m"
    with pytest.raises(DatasetError, match=message):
        sample_episodes(tiny_room, "commongoal", 2, "hard", 5, rng,
                        SamplingConfig(max_goal_tries=20))


def test_unknown_names_are_errors(door_scene):
    rng = np.random.default_rng(0)
    with pytest.raises(DatasetError, match="unknown task 'multigoal'"):
        sample_episodes(door_scene, "multigoal", 2, "easy", 1, rng)
    with pytest.raises(DatasetError, match="unknown difficulty 'extreme'"):
        sample_episodes(door_scene, "commongoal", 2, "extreme", 1, rng)
    with pytest.raises(DatasetError, match="unknown preset 'huge'"):
        get_preset("huge")
    with pytest.raises(DatasetError, match="unknown split 'dev'"):
        PRESET.counts("dev")
    with pytest.raises(DatasetError, match="eval-agents"):
        agents_for_split("commongoal", 2, 3, "val")
    with pytest.raises(DatasetError, match="eval-agents"):
        agents_for_split("adhocoop", 4, None, "val")


def test_adhocoop_trains_with_n_and_evaluates_with_n_prime(tmp_path, door_scene):
    assert [agents_for_split("adhocoop", 2, None, s) for s in ("train", "val")] == [2, 3]
    common = generate_dataset(tmp_path / "c", [door_scene], "commongoal", 2, "train",
                              "small", progress=False)
    [train] = generate_dataset(tmp_path / "a", [door_scene], "adhocoop", 2, "train",
                               "small", progress=False)
    [val] = generate_dataset(tmp_path / "a", [door_scene], "adhocoop", 2, "val", "small",
                             progress=False)
    assert train.parent.parent.name == "adhocoop_n2to3"
    a, v, c = (load_episode_file(p) for p in (train, val, common[0]))
    assert (a.num_agents, v.num_agents, a.task) == (2, 3, "adhocoop")
    assert len(v.episodes) == 30 and all(e.num_agents == 3 for e in v.episodes)
    # Ad-hoCoop trains on the CommonGoal episodes of the training N.
    for ea, ec in zip(a.episodes, c.episodes, strict=True):
        np.testing.assert_array_equal(ea.start_positions, ec.start_positions)


def test_same_seed_gives_byte_identical_files(tmp_path, door_scene, open_room):
    def files(root: Path) -> dict[str, bytes]:
        return {p.relative_to(root).as_posix(): p.read_bytes()
                for p in sorted(root.rglob("*")) if p.is_file()}

    for out in ("a", "b"):
        generate_dataset(tmp_path / out, [door_scene, open_room], "specificgoal", 3, "val",
                         "small", seed=7, progress=False)
    generate_dataset(tmp_path / "c", [door_scene], "specificgoal", 3, "val", "small",
                     seed=8, progress=False)
    a, b = files(tmp_path / "a"), files(tmp_path / "b")
    assert set(a) == {"index.json", "specificgoal_n3/val/door.json.gz",
                      "specificgoal_n3/val/open-room.json.gz"}
    assert a == b
    other = files(tmp_path / "c")
    assert other["specificgoal_n3/val/door.json.gz"] != a["specificgoal_n3/val/door.json.gz"]


@pytest.fixture()
def episode_file(tmp_path, door_scene) -> Path:
    [path] = generate_dataset(tmp_path, [door_scene], "commongoal", 2, "test", "small",
                              progress=False)
    return path


def test_round_trip_and_scene_check(episode_file, door_scene, open_room):
    content = load_episode_file(episode_file, door_scene)
    assert len(content.episodes) == 30 and content.generator["seed"] == 0
    assert content.scene.content_hash == door_scene.content_hash
    with pytest.raises(DatasetError, match=r"scene 'door'.*given scene 'open-room'"):
        load_episode_file(episode_file, open_room)


def test_edited_file_is_refused(episode_file):
    doc = json.loads(gzip.decompress(episode_file.read_bytes()))
    doc["episodes"][0]["start_positions"][0][0] += 0.5
    episode_file.write_bytes(gzip.compress(json.dumps(doc).encode()))
    with pytest.raises(DatasetError, match="modified after it was written"):
        load_episode_file(episode_file)
    doc["schema_version"] = 99
    episode_file.write_bytes(gzip.compress(json.dumps(doc).encode()))
    with pytest.raises(DatasetError, match="schema version 99"):
        load_episode_file(episode_file)
    episode_file.write_bytes(b"not gzip")
    with pytest.raises(DatasetError, match="cannot read"):
        load_episode_file(episode_file)


def test_failed_write_leaves_no_half_file(tmp_path, episode_file, monkeypatch):
    content = load_episode_file(episode_file)
    before = episode_file.read_bytes()

    def broken_fsync(fd: int) -> None:
        raise OSError("disk full")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    fresh = tmp_path / "new" / "x.json.gz"
    for target in (fresh, episode_file):
        with pytest.raises(OSError, match="disk full"):
            save_episode_file(target, content)
    assert not fresh.exists() and list(fresh.parent.iterdir()) == []
    assert episode_file.read_bytes() == before
    assert [p.name for p in episode_file.parent.iterdir()] == [episode_file.name]


def test_dataset_loads_and_verifies_index(tmp_path, episode_file, door_scene, open_room):
    root = episode_file.parents[2]
    ds = Dataset.load(root, scenes={"door": door_scene})
    assert len(ds) == 30 and len(list(ds.episodes("hard"))) == 10
    assert len(Dataset.load(root, split="val").files) == 0
    with pytest.raises(DatasetError, match="given scene 'open-room'"):
        Dataset.load(root, scenes={"door": open_room})
    content = load_episode_file(episode_file)
    save_episode_file(episode_file, EpisodeFile(
        content.task, content.num_agents, content.split, content.scene,
        content.generator, content.episodes[:5]))
    with pytest.raises(DatasetError, match="does not match its entry"):
        Dataset.load(root)
    with pytest.raises(DatasetError, match="not an episode dataset"):
        Dataset.load(tmp_path / "nowhere")


def test_cli_generate_and_info(tmp_path, door_scene, capsys):
    scene_file = tmp_path / "door.npz"
    door_scene.save(scene_file)
    cmd = tyro.cli(DatasetGenerate, args=[
        "--task", "specificgoal", "--agents", "2", "--split", "val", "--preset", "small",
        "--out", str(tmp_path / "ds"), "--scenes", str(scene_file), "--quiet"])
    assert cmd.run() == 0
    assert (tmp_path / "ds" / "specificgoal_n2" / "val" / "door.json.gz").is_file()
    capsys.readouterr()
    assert DatasetInfo(tmp_path / "ds", json=True).run() == 0
    info = json.loads(capsys.readouterr().out)
    assert info["episodes"] == 30
    assert info["files"][0]["difficulties"] == {"easy": 10, "medium": 10, "hard": 10}
    assert sum(info["histograms"]["specificgoal_n2/val"]) == 60  # 30 episodes × 2 agents
    assert DatasetInfo(tmp_path / "ds").run() == 0
    text = capsys.readouterr().out
    assert "door" in text and f"fingerprint {info['fingerprint']}" in text
    # the same command again: the same fingerprint; another seed: another one
    for name, seed, same in (("again", "0", True), ("seed1", "1", False)):
        assert tyro.cli(DatasetGenerate, args=[
            "--task", "specificgoal", "--agents", "2", "--split", "val", "--preset", "small",
            "--out", str(tmp_path / name), "--scenes", str(scene_file), "--quiet",
            "--seed", seed]).run() == 0
        capsys.readouterr()
        assert DatasetInfo(tmp_path / name, json=True).run() == 0
        other = json.loads(capsys.readouterr().out)["fingerprint"]
        assert (other == info["fingerprint"]) is same


def _y_up_centimetre_room(path: Path) -> Path:
    """A 7 × 5 m room in centimetres, Y up, as OBJ: a file needing two load options."""
    import trimesh

    parts = []
    for lo, hi in (((0, 0, -0.1), (7, 5, 0)), ((0, 0, 0), (7, 0.1, 2.5)),
                   ((0, 4.9, 0), (7, 5, 2.5)), ((0, 0, 0), (0.1, 5, 2.5)),
                   ((6.9, 0, 0), (7, 5, 2.5)), ((3, 2, 0), (4, 3, 1))):
        box = trimesh.creation.box(extents=np.subtract(hi, lo))
        box.apply_translation(np.add(lo, hi) / 2)
        parts.append(box)
    mesh = trimesh.util.concatenate(parts)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    mesh.apply_scale(100.0)
    mesh.export(path)
    return path


def test_dataset_from_a_y_up_scene_reloads_its_scene_from_what_it_recorded(tmp_path):
    from collavn.datasets.episode import SceneRef
    from collavn.scenes import SceneSpec, load_scene

    path = _y_up_centimetre_room(tmp_path / "hall.obj")
    scene = load_scene(SceneSpec(str(path), up_axis="y", scale=0.01), cache=False)
    episodes = sample_episodes(scene, "commongoal", 2, "easy", 3, np.random.default_rng(0))
    out = tmp_path / "hall.json.gz"
    save_episode_file(out, EpisodeFile("commongoal", 2, "val", SceneRef.of(scene),
                                       {"seed": 0}, tuple(episodes)))
    content = load_episode_file(out)
    assert content.scene.spec == SceneSpec(str(path.resolve()), up_axis="y", scale=0.01)
    again = load_scene(content.scene.spec, cache_dir=tmp_path / "cache")
    content.check_scene(again)  # the same scene, from the record alone
    assert load_episode_file(out, again).episodes[0].episode_id == episodes[0].episode_id
    other = load_scene(content.scene.spec.source, scale=0.011, cache=False)
    with pytest.raises(DatasetError, match=r"loaded as .*hall\.obj \(up_axis='y', scale=0\.01, "
                                           r"floor_height=None\).*loaded as .*"
                                           r"up_axis='auto', scale=0\.011.*--up-axis"):
        content.check_scene(other)


def test_old_episode_files_without_a_spec_still_load(tmp_path, door_scene):
    from collavn.datasets.episode import SceneRef
    from collavn.scenes import SceneSpec

    ref = SceneRef(door_scene.name, "procedural:4", door_scene.content_hash)  # no spec
    assert "spec" not in ref.to_json()
    episodes = sample_episodes(door_scene, "commongoal", 2, "easy", 1,
                               np.random.default_rng(0))
    out = tmp_path / "old.json.gz"
    save_episode_file(out, EpisodeFile("commongoal", 2, "val", ref, {}, tuple(episodes)))
    content = load_episode_file(out, door_scene)
    assert content.scene.recorded_spec is None
    assert content.scene.spec == SceneSpec("procedural:4")
    with pytest.raises(DatasetError, match="options not recorded"):
        content.check_scene(door_scene.__class__(**{**_fields(door_scene),
                                                    "vertices": door_scene.vertices + 1}))
    with pytest.raises(DatasetError, match="malformed scene reference"):
        SceneRef.from_json({"name": "a", "source": "b", "content_hash": "c",
                            "spec": {"source": "b", "scale": -1}})


def _fields(scene: Scene) -> dict:
    import dataclasses

    return {f.name: getattr(scene, f.name) for f in dataclasses.fields(scene)
            if f.name != "_fields"}
