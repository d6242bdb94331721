import time

import numpy as np
import pytest
import trimesh

from collavn.errors import SceneError
from collavn.scenes import Scene, load_scene
from collavn.scenes.meshes import find_floors, load_mesh_scene
from collavn.scenes.summary import scene_summary


def _room_mesh(z_up: bool = True) -> trimesh.Trimesh:
    """A 6×4 m floor with a 1 m block on it, vertex-coloured; Y-up if asked."""
    floor = trimesh.creation.box(extents=(6, 4, 0.1))
    floor.apply_translation((3, 2, -0.05))
    block = trimesh.creation.box(extents=(1, 1, 1))
    block.apply_translation((3, 2, 0.5))
    mesh = trimesh.util.concatenate([floor, block])
    mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.tile([200, 50, 50, 255],
                                                                          (len(mesh.vertices), 1)))
    if not z_up:  # (x, y, z) → (x, z, -y): the Y-up convention of glTF
        mesh.apply_transform(trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0)))
    return mesh


def test_ply_import_keeps_vertex_colours_and_finds_the_floor(tmp_path):
    path = tmp_path / "room.ply"
    _room_mesh().export(path)
    scene = load_mesh_scene(path)
    assert scene.floor_z == pytest.approx(0.0, abs=1e-6)
    assert (scene.face_tint == [200, 50, 50]).all()
    assert scene.nav.is_navigable(np.array([[1.0, 1.0]]))[0]
    assert not scene.nav.is_navigable(np.array([[3.0, 2.0]]))[0]  # the block


def test_y_up_file_with_up_axis_y_equals_the_z_up_scene(tmp_path):
    z_path, y_path = tmp_path / "room_z.obj", tmp_path / "room_y.obj"
    _room_mesh().export(z_path)
    _room_mesh(z_up=False).export(y_path)
    z_scene, y_scene = load_mesh_scene(z_path), load_mesh_scene(y_path, up_axis="y")
    np.testing.assert_allclose(y_scene.bounds, z_scene.bounds, atol=1e-5)
    assert y_scene.nav.navigable.sum() == z_scene.nav.navigable.sum() > 0
    with pytest.raises(SceneError, match="up_axis must be"):
        load_mesh_scene(y_path, up_axis="w")  # type: ignore[arg-type]


def test_bad_inputs_are_clear_errors(tmp_path):
    with pytest.raises(SceneError, match="not found"):
        load_mesh_scene(tmp_path / "missing.glb")
    corrupt = tmp_path / "corrupt.glb"
    corrupt.write_bytes(b"glTF this is not a real binary gltf")
    with pytest.raises(SceneError, match="cannot read mesh"):
        load_mesh_scene(corrupt)
    wrong = tmp_path / "scene.txt"
    wrong.write_text("hello")
    with pytest.raises(SceneError, match="unsupported mesh format"):
        load_mesh_scene(wrong)
    wall = tmp_path / "wall.ply"
    trimesh.creation.box(extents=(0.1, 5, 2.5)).export(wall)  # a wall, nothing to stand on
    with pytest.raises(SceneError, match=r"no navigable area|no floor"):
        load_mesh_scene(wall)
    room = tmp_path / "room.ply"
    _room_mesh().export(room)
    with pytest.raises(SceneError, match=r"no floor at height 5.00"):
        load_mesh_scene(room, floor_height=5.0)
    with pytest.raises(SceneError, match="scale"):
        load_mesh_scene(room, scale=float("nan"))


def test_find_floors_picks_each_storey():
    storey = trimesh.creation.box(extents=(10, 10, 0.1)).triangles
    two = np.concatenate([storey, storey + [0, 0, 3.0]])
    assert find_floors(two) == pytest.approx([0.05, 3.05], abs=0.03)


def test_cache_round_trip_gives_the_same_scene(tmp_path):
    path = tmp_path / "room.ply"
    _room_mesh().export(path)
    first = load_scene(str(path), cache_dir=tmp_path / "cache")
    assert len(list((tmp_path / "cache").glob("*.npz"))) == 1
    second = load_scene(str(path), cache_dir=tmp_path / "cache")
    assert second.content_hash == first.content_hash
    np.testing.assert_array_equal(second.nav.components, first.nav.components)
    # a damaged cache file is rebuilt, not trusted
    cached = next((tmp_path / "cache").glob("*.npz"))
    cached.write_bytes(b"garbage")
    third = load_scene(str(path), cache_dir=tmp_path / "cache")
    assert third.content_hash == first.content_hash


def test_saved_scene_of_another_format_version_is_refused(tmp_path, door_scene):
    path = tmp_path / "s.npz"
    door_scene.save(path)
    loaded = Scene.load(path)
    assert loaded.content_hash == door_scene.content_hash
    data = dict(np.load(path))
    data["version"] = np.int64(999)
    np.savez(path, **data)
    with pytest.raises(SceneError, match="scene format 999"):
        Scene.load(path)


def test_real_house_imports_and_is_one_building(tmp_path, shared_scene):
    path = shared_scene("aws_small_house.glb")
    start = time.perf_counter()
    scene = load_scene(str(path), cache_dir=tmp_path)
    assert time.perf_counter() - start < 60  # generous: the benchmark measures speed
    info = scene_summary(scene)
    assert info["triangles"] == 145_844
    assert len(scene.textures) >= 2  # its texture survived
    assert 80 < info["navigable_area_m2"] < 200
    assert info["component_areas_m2"][0] > 0.95 * info["navigable_area_m2"]
    assert 10 < info["largest_geodesic_m"] < 40


def test_real_office_is_large_and_connected(tmp_path, shared_scene):
    scene = load_scene(str(shared_scene("willowgarage_office.glb")), cache_dir=tmp_path)
    info = scene_summary(scene)
    assert info["extent_m"][0] > 50
    assert info["component_areas_m2"][0] > 0.98 * info["navigable_area_m2"] > 1000
