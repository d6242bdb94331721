"""SceneSpec, units, up axes, size guards, the ceiling rule, Draco and load warnings.

Every fixture is written here, in ``tmp_path``: a furnished 8 × 6 m room in metres,
centimetres, Y up or Z up, as OBJ, glTF or COLLADA.
"""

from __future__ import annotations

import re
import sys
import time
import warnings

import numpy as np
import pytest
import trimesh

from collavn.errors import SceneError, SceneWarning
from collavn.rendering.cameras import CameraSpec
from collavn.rendering.renderer import Renderer
from collavn.scenes import SceneSpec, SizeLimits, load_scene
from collavn.scenes.builder import SceneBuilder, flat_texture
from collavn.scenes.loading import cache_path
from collavn.scenes.meshes import load_mesh_scene
from collavn.scenes.navigation import NavConfig
from collavn.scenes.orientation import warn_if_implausible

Y_UP = trimesh.transformations.rotation_matrix(-np.pi / 2, (1, 0, 0))  # z → +y


def room(height: float = 3.2, ceiling_grid: bool = False) -> trimesh.Trimesh:
    """An 8 × 6 m room, Z up, metres: floor slab, four walls, a 1 m block."""
    parts = [_box((0, 0, -0.1), (8, 6, 0)), _box((3, 2, 0), (4, 3, 1))]
    parts += [_box(lo, hi) for lo, hi in (((0, 0, 0), (8, 0.1, height)),
                                          ((0, 5.9, 0), (8, 6, height)),
                                          ((0, 0, 0), (0.1, 6, height)),
                                          ((7.9, 0, 0), (8, 6, height)))]
    if ceiling_grid:
        parts.append(_panel_grid(z=3.0))
    return trimesh.util.concatenate(parts)


def _box(lo, hi) -> trimesh.Trimesh:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    box = trimesh.creation.box(extents=hi - lo)
    box.apply_translation((lo + hi) / 2)
    return box


def _panel_grid(z: float, size: float = 0.5, pitch: float = 1.0) -> trimesh.Trimesh:
    """One-sided ceiling panels facing up (seen from below: their backs), with gaps."""
    vertices, faces = [], []
    for x0 in np.arange(0.3, 7.6, pitch):
        for y0 in np.arange(0.3, 5.6, pitch):
            k = len(vertices)
            vertices += [(x0, y0, z), (x0 + size, y0, z), (x0 + size, y0 + size, z),
                         (x0, y0 + size, z)]
            faces += [(k, k + 1, k + 2), (k, k + 2, k + 3)]
    return trimesh.Trimesh(np.array(vertices), np.array(faces), process=False)


def export(mesh: trimesh.Trimesh, path, scale: float = 1.0, y_up: bool = False):
    mesh = mesh.copy()
    if y_up:
        mesh.apply_transform(Y_UP)
    mesh.apply_scale(scale)
    mesh.export(path)
    return path


def collada(path, mesh: trimesh.Trimesh, unit: float, up: str):
    """Write ``mesh`` as COLLADA declaring ``<unit meter=unit>`` and ``<up_axis>up``."""
    text = trimesh.exchange.dae.export_collada(mesh)
    text = text.decode() if isinstance(text, bytes) else text
    text = re.sub(r"<up_axis>.*?</up_axis>", "", text)
    text = text.replace("</asset>", f'<unit meter="{unit}" name="u"/>'
                                    f"<up_axis>{up}</up_axis></asset>")
    path.write_text(text)
    return path


@pytest.fixture(scope="module")
def metre_room(tmp_path_factory):
    path = export(room(), tmp_path_factory.mktemp("m") / "room.ply")
    return load_scene(path, cache=False)


def _no_grid(monkeypatch):
    """Fail the test if a navigation grid is rasterised."""
    def boom(*args, **kwargs):
        raise AssertionError("the grid was allocated")
    monkeypatch.setattr("collavn.scenes.navigation.floor_cells", boom)


# ------------------------------------------------------------------ SceneSpec
def test_spec_round_trips_and_validates():
    spec = SceneSpec("hall.obj", up_axis="y", scale=0.01, floor_height=3.0)
    assert SceneSpec.from_dict(spec.to_dict()) == spec
    assert SceneSpec.of("hall.obj", up_axis="y", scale=0.01, floor_height=3.0) == spec
    assert SceneSpec.of(spec) is spec
    assert SceneSpec.of(spec, scale=1.0).options == {"up_axis": "y", "floor_height": 3.0}
    assert "up_axis='y'" in spec.describe() and "scale=0.01" in str(spec)
    assert SceneSpec.of("procedural:3").kind == "procedural"
    bad = [
        (dict(scale=0.0), "scale must be a finite positive"),
        (dict(scale=float("nan")), "scale must be a finite positive"),
        (dict(scale=-1.0), "scale must be a finite positive"),
        (dict(floor_height=float("inf")), "floor_height must be a finite"),
        (dict(up_axis="w"), "up_axis must be one of auto, x, y, z"),
        (dict(units="cm"), "unknown scene load option"),
    ]
    for options, message in bad:
        with pytest.raises(SceneError, match=message):
            SceneSpec.of("hall.obj", **options)
    with pytest.raises(SceneError, match="only apply to mesh files"):
        SceneSpec("procedural:3", up_axis="y")
    with pytest.raises(SceneError, match="seed must be an integer"):
        SceneSpec("procedural:x")
    with pytest.raises(SceneError, match="needs a 'source'"):
        SceneSpec.from_dict({"scale": 2.0})
    with pytest.raises(SceneError, match="non-empty string"):
        SceneSpec("")
    with pytest.raises(SceneError, match="a string or a SceneSpec"):
        SceneSpec.of(3)  # type: ignore[arg-type]


def test_cache_key_is_one_per_spec(tmp_path):
    path = export(room(), tmp_path / "room.ply")
    nav = NavConfig()
    same = {cache_path(SceneSpec.of(p), nav, tmp_path)
            for p in (str(path), SceneSpec(str(path)), SceneSpec(str(path), up_axis="auto"))}
    assert len(same) == 1
    assert cache_path(SceneSpec(str(path), up_axis="z"), nav, tmp_path) not in same
    assert cache_path(SceneSpec(str(path), scale=2.0), nav, tmp_path) not in same
    # The string and the spec load through one cache file, and the scene records its spec.
    first = load_scene(str(path), cache_dir=tmp_path / "c")
    second = load_scene(SceneSpec(str(path)), cache_dir=tmp_path / "c")
    assert len(list((tmp_path / "c").glob("*.npz"))) == 1
    assert first.spec == second.spec == SceneSpec(str(path.resolve()))
    assert first.source == str(path.resolve())


def test_saved_scene_keeps_its_spec(tmp_path, metre_room):
    metre_room.save(tmp_path / "s.npz")
    from collavn.scenes.scene import Scene

    assert Scene.load(tmp_path / "s.npz").spec == metre_room.spec
    again = load_scene(str(tmp_path / "s.npz"))
    assert again.content_hash == metre_room.content_hash
    assert again.spec == SceneSpec(str((tmp_path / "s.npz").resolve()))
    with pytest.raises(SceneError, match="only apply to mesh files"):
        load_scene(str(tmp_path / "s.npz"), scale=2.0)


# ---------------------------------------------------------------------- units
def test_centimetre_collada_room_loads_in_metres(tmp_path, metre_room):
    cm = room()
    cm.apply_scale(100.0)
    scene = load_scene(collada(tmp_path / "room.dae", cm, 0.01, "Z_UP"), cache=False)
    np.testing.assert_allclose(scene.bounds, metre_room.bounds, atol=1e-3)
    assert scene.nav.navigable.sum() == metre_room.nav.navigable.sum() > 0
    # The same room written Y up and declared so comes out the same.
    cm.apply_transform(Y_UP)
    y_scene = load_scene(collada(tmp_path / "room_y.dae", cm, 0.01, "Y_UP"), cache=False)
    np.testing.assert_allclose(y_scene.bounds, metre_room.bounds, atol=1e-3)


def test_collada_declaring_the_wrong_up_axis_warns(tmp_path):
    path = collada(tmp_path / "room.dae", room(), 1.0, "Y_UP")  # Z-up data, as trimesh writes
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_mesh_scene(path)  # on its side: one wall becomes the floor
    messages = [str(w.message) for w in caught if issubclass(w.category, SceneWarning)]
    assert len(messages) == 2
    assert re.search(r"declares Y up but the geometry is thinnest along Z.*up_axis='z'",
                     messages[0])
    assert re.search(r"taller \(6\.0 m\) than it is wide \(3\.3 m\).*up axis Y "
                     r"\(declared by the file\)", messages[1])
    scene = load_mesh_scene(path, up_axis="z")  # the fix it names
    assert scene.nav.components.max() == 1 and scene.bounds[1, 2] == pytest.approx(3.2)


def test_centimetre_obj_is_refused_fast_and_loads_with_scale(tmp_path, metre_room,
                                                            monkeypatch):
    path = export(room(), tmp_path / "room.obj", scale=100.0)
    with monkeypatch.context() as m:
        _no_grid(m)
        start = time.perf_counter()
        with pytest.raises(SceneError, match=r"spans 800.0 × 600.0 × 330.0 m.*scale=0.01"):
            load_scene(path, cache=False)
        assert time.perf_counter() - start < 0.5
    scene = load_scene(path, scale=0.01, cache=False)
    np.testing.assert_allclose(scene.bounds, metre_room.bounds, atol=1e-4)
    assert scene.spec == SceneSpec(str(path.resolve()), scale=0.01)


def test_grid_guard_names_the_footprint_before_allocating(tmp_path, monkeypatch):
    path = export(room(), tmp_path / "room.ply")
    _no_grid(monkeypatch)
    with pytest.raises(SceneError, match=r"8\.3 × 6\.3 m floor plan needs a navigation grid "
                                         r"of 5,229 cells .*limit of 1,000.*--scale"):
        load_scene(path, cache=False, limits=SizeLimits(max_grid_cells=1000))


@pytest.mark.parametrize("far", [2000.0, 1e30])
def test_a_stray_vertex_far_away_is_refused_with_its_size(tmp_path, monkeypatch, far):
    mesh = room()
    stray = trimesh.Trimesh(mesh.vertices[:3] + [far, 0, 0], [[0, 1, 2]], process=False)
    path = export(trimesh.util.concatenate([mesh, stray]), tmp_path / "stray.ply")
    _no_grid(monkeypatch)
    size = "2,00" if far < 1e4 else "1e\\+30"
    with pytest.raises(SceneError, match=rf"spans {size}.*stray vertex"):
        load_scene(path, cache=False)


def test_size_limits_are_validated():
    with pytest.raises(SceneError, match="max_extent must be a positive"):
        SizeLimits(max_extent=float("nan"))
    with pytest.raises(SceneError, match="max_grid_cells must be positive"):
        SizeLimits(max_grid_cells=0)


# -------------------------------------------------------------------- up axes
@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_y_up_file_loads_with_default_options(tmp_path, metre_room, suffix):
    path = export(room(), tmp_path / f"room{suffix}", y_up=True)
    scene = load_scene(path, cache=False)
    np.testing.assert_allclose(scene.bounds, metre_room.bounds, atol=1e-4)
    assert scene.nav.navigable.sum() == metre_room.nav.navigable.sum()
    assert scene.spec is not None and scene.spec.up_axis == "auto"


def test_z_up_gltf_loads_with_default_options(tmp_path, metre_room):
    """Real glTF exports often keep Z up (the shared scenes do): the geometry decides."""
    scene = load_scene(export(room(), tmp_path / "room.glb"), cache=False)
    np.testing.assert_allclose(scene.bounds, metre_room.bounds, atol=1e-4)


def test_implausible_scene_warns_and_names_the_options(open_room):
    b = SceneBuilder(8)
    m = b.material("m", flat_texture((100, 100, 100), 8))
    b.add_box((0, 0, -0.1), (6, 6, 0), m)  # 36 m² of floor ...
    b.add_box((-30, -30, 20), (30, 30, 20.1), m)  # ... under a 60 × 60 m slab 20 m up
    with pytest.warns(SceneWarning, match=r"navigable.*lies 10 m below.*up axis Z "
                                          r"\(detected from the geometry\).*up_axis='y'"):
        warn_if_implausible(b.build("odd"), "z", "detected from the geometry")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_if_implausible(open_room, "z", "requested")


def test_no_floor_error_suggests_the_other_axes(tmp_path):
    wall = trimesh.Trimesh([[0, 0, 0], [0, 5, 0], [0, 5, 2.5], [0, 0, 2.5]],
                           [[0, 1, 2], [0, 2, 3]], process=False)
    path = export(wall, tmp_path / "wall.ply")
    with pytest.raises(SceneError, match=r"no horizontal floor surface found with Z up; "
                                         r"if the file is oriented otherwise, try "
                                         r"up_axis='y' or 'x'"):
        load_mesh_scene(path)


# ----------------------------------------------------------- ceiling grid rule
def test_suspended_ceiling_grid_does_not_chop_the_floor(tmp_path, metre_room):
    scene = load_scene(export(room(ceiling_grid=True), tmp_path / "grid.ply"), cache=False)
    assert scene.nav.components.max() == 1
    np.testing.assert_array_equal(scene.nav.navigable, metre_room.nav.navigable)


def test_a_closed_cabinet_taller_than_the_robot_is_still_solid():
    b = SceneBuilder(8)
    m = b.material("m", flat_texture((100, 100, 100), 8))
    b.add_box((0, 0, -0.1), (8, 8, 0), m)
    b.add_box((3, 3, 0), (5.5, 5.5, 2.0), m)  # hollow inside, top 2 m up
    scene = b.build("cabinet")
    assert not scene.nav.floor[scene.nav.to_cell(np.array([4.25, 4.25]))]
    assert scene.nav.components.max() == 1


# ---------------------------------------------------------- Draco, textures
def test_draco_compressed_gltf_loads(tmp_path, metre_room):
    pytest.importorskip("DracoPy")  # a dependency of collavn: present when installed
    path = tmp_path / "room.glb"
    mesh = room()
    path.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(mesh),
                                                      extension_draco=True))
    assert b"KHR_draco_mesh_compression" in path.read_bytes()[:4000]
    scene = load_scene(path, cache=False)
    np.testing.assert_allclose(scene.bounds, metre_room.bounds, atol=0.01)


def test_draco_without_decoder_fails_once_naming_the_fix(tmp_path, monkeypatch):
    pytest.importorskip("DracoPy")
    path = tmp_path / "room.glb"
    path.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(room()),
                                                      extension_draco=True))
    monkeypatch.setitem(sys.modules, "DracoPy", None)  # import now fails
    with pytest.raises(SceneError, match=r"Draco-compressed.*pip install DracoPy"):
        load_scene(path, cache=False)


def test_missing_texture_file_warns_once(tmp_path):
    path = export(room(), tmp_path / "room.obj")
    text = path.read_text()
    path.write_text("mtllib room_tex.mtl\nusemtl wood\n" + text)
    (tmp_path / "room_tex.mtl").write_text("newmtl wood\nKd 1 1 1\nmap_Kd wood.png\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        load_mesh_scene(path)
    ours = [w for w in caught if issubclass(w.category, SceneWarning)]
    assert len(ours) == 1
    assert "texture file(s) not found: wood.png" in str(ours[0].message)


def test_missing_collada_and_gltf_textures_are_listed(tmp_path):
    from collavn.scenes.mesh_files import read_facts

    dae = tmp_path / "a.dae"
    dae.write_text('<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema">'
                   '<asset><unit meter="0.0254"/><up_axis>Z_UP</up_axis></asset>'
                   '<library_images><image id="i"><init_from>tex/brick.jpg</init_from>'
                   '</image></library_images></COLLADA>')
    facts = read_facts(dae)
    assert (facts.unit, facts.up_axis, facts.missing_textures) == (0.0254, "z",
                                                                   ("tex/brick.jpg",))
    gltf = tmp_path / "a.gltf"
    gltf.write_text('{"asset": {"version": "2.0"}, "images": [{"uri": "my%20tile.png"}, '
                    '{"uri": "data:image/png;base64,AAAA"}]}')
    assert read_facts(gltf).missing_textures == ("my tile.png",)
    (tmp_path / "bad.dae").write_text("<COLLADA><asset><unit meter='-1'/></asset></COLLADA>")
    with pytest.raises(SceneError, match="not a positive length"):
        read_facts(tmp_path / "bad.dae")
    (tmp_path / "broken.dae").write_text("<COLLADA><asset>")
    with pytest.raises(SceneError, match="malformed COLLADA"):
        read_facts(tmp_path / "broken.dae")


# ------------------------------------------------------------ off-map renders
def test_pose_off_the_map_warns_once(open_room):
    small = CameraSpec.panorama(32, 8)
    with Renderer(open_room, panorama=small, goal=CameraSpec.pinhole(8, 8)) as renderer:
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            renderer.render(np.array([[4.0, 4.0, 0.0]]))
        with pytest.warns(SceneWarning, match=r"pose 1 at \(40.00, 4.00\) is off the "
                                              r"navigable map"):
            renderer.render(np.array([[4.0, 4.0, 0.0], [40.0, 4.0, 0.0]]))
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            renderer.render(np.array([[40.0, 4.0, 0.0]]))


# ------------------------------------------------------------------------ CLI
def test_every_scene_command_takes_the_load_options(tmp_path, capsys):
    """A Y-up OBJ in centimetres, from `scene info` to `viz`, on the command line only."""
    import json

    from collavn.cli import main
    from collavn.evaluation.runner import read_trajectories

    path = export(room(), tmp_path / "hall.obj", scale=100.0, y_up=True)
    load = ["--up-axis", "y", "--scale", "0.01"]
    assert main(["scene", "info", str(path)]) == 2  # the guard, not a crash
    assert "--scale" in capsys.readouterr().err
    assert main(["scene", "info", str(path), *load, "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["extent_m"][:2] == pytest.approx([8.0, 6.0], abs=0.01)
    assert main(["render", str(path), *load, "--width", "64", "--height", "16", "--out",
                 str(tmp_path / "view.png")]) == 0
    assert (tmp_path / "view.png").is_file()
    data = tmp_path / "data"
    assert main(["dataset", "generate", "--split", "val", "--episodes", "1", "--scenes",
                 str(path), *load, "--out", str(data), "--quiet"]) == 0
    small = ["--panorama-width", "32", "--panorama-height", "8", "--goal-size", "8"]
    assert main(["evaluate", "--policy", "random", "--dataset", str(data), "--out",
                 str(tmp_path / "eval"), "--no-progress", *small]) == 0
    traj = read_trajectories(tmp_path / "eval" / "trajectories.jsonl")[0]
    assert traj.scene == SceneSpec(str(path.resolve()), up_axis="y", scale=0.01)
    assert main(["viz", str(tmp_path / "eval"), "--out", str(tmp_path / "viz"), "--gifs",
                 "0"]) == 0
    # options for a scene that takes none are refused by name
    assert main(["render", "procedural:0", "--scale", "2"]) == 2
    assert "scale" in capsys.readouterr().err


def test_a_dataset_made_in_python_from_a_y_up_scene_evaluates_from_the_cli(tmp_path, capsys):
    from collavn.cli import main
    from collavn.datasets.build import generate_dataset

    path = export(room(), tmp_path / "room.glb", y_up=True)
    scene = load_scene(SceneSpec(str(path), up_axis="y"))
    data = tmp_path / "data"
    generate_dataset(data, [scene], "commongoal", 2, "val", preset="small", progress=False)
    assert main(["evaluate", "--policy", "oracle", "--dataset", str(data), "--difficulty",
                 "easy", "--out", str(tmp_path / "eval"), "--no-progress",
                 "--panorama-width", "32", "--panorama-height", "8", "--goal-size", "8",
                 "--json"]) == 0
    assert '"SR"' in capsys.readouterr().out


def test_scene_info_and_render_share_one_cache_entry(tmp_path, monkeypatch):
    from collavn.cli import main

    monkeypatch.setenv("COLLAVN_CACHE", str(tmp_path / "cache"))
    path = export(room(), tmp_path / "room.ply")
    assert main(["scene", "info", str(path), "--json"]) == 0
    assert main(["render", str(path), "--width", "32", "--height", "8", "--out",
                 str(tmp_path / "v.png")]) == 0
    assert len(list((tmp_path / "cache").rglob("*.npz"))) == 1


def test_scene_word_alone_lists_its_subcommands(capsys):
    from collavn.cli import main

    assert main(["scene", "--help"]) == 0
    out = capsys.readouterr().out
    assert "scene info" in out and "train" not in out
    assert main(["dataset"]) == 2
    assert "dataset generate" in capsys.readouterr().err
