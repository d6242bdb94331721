"""Renderer: exact depths and mapping on hand-built rooms, bodies, errors, Warp vs Embree."""

from __future__ import annotations

import sys

import numpy as np
import pytest

from collavn.errors import RenderError
from collavn.rendering import BODY_PALETTE, CameraSpec, Lighting, Renderer
from collavn.scenes.builder import SceneBuilder, flat_texture
from collavn.scenes.scene import Scene

# Camera at (2, 0): walls 3 m ahead (+x), 5 m behind, 2 m to the right (−y), 4 m left.
CAM = (2.0, 0.0)
AHEAD, BEHIND, RIGHT, LEFT = 3.0, 5.0, 2.0, 4.0
WALL_COLOURS = {"front": (200, 40, 40), "back": (40, 200, 40), "right": (40, 40, 200),
                "left": (200, 200, 40)}


def _checker(a: tuple[int, int, int], b: tuple[int, int, int], size: int = 16) -> np.ndarray:
    cells = (np.arange(size)[:, None] // 4 + np.arange(size)[None] // 4) % 2 == 0
    return np.where(cells[..., None], np.array(a, np.uint8), np.array(b, np.uint8))


@pytest.fixture(scope="module")
def room() -> Scene:
    """Four differently coloured walls around the camera, a floor and a ceiling."""
    b = SceneBuilder(texture_size=16)
    floor = b.material("floor", _checker((150, 120, 90), (90, 70, 50)))
    ceiling = b.material("ceiling", flat_texture((240, 240, 230), 16))
    walls = {k: b.material(k, flat_texture(c, 16)) for k, c in WALL_COLOURS.items()}
    x0, x1, y0, y1 = CAM[0] - BEHIND, CAM[0] + AHEAD, CAM[1] - RIGHT, CAM[1] + LEFT
    b.add_box((x0, y0, -0.1), (x1, y1, 0.0), floor)
    b.add_box((x0, y0, 2.5), (x1, y1, 2.6), ceiling)
    b.add_box((x1, y0 - 0.2, 0), (x1 + 0.2, y1 + 0.2, 2.5), walls["front"])
    b.add_box((x0 - 0.2, y0 - 0.2, 0), (x0, y1 + 0.2, 2.5), walls["back"])
    b.add_box((x0, y0 - 0.2, 0), (x1, y0, 2.5), walls["right"])
    b.add_box((x0, y1, 0), (x1, y1 + 0.2, 2.5), walls["left"])
    return b.build("four-walls")


@pytest.fixture(scope="module")
def textured() -> Scene:
    """Two rooms joined by a door, checker textures everywhere, a few table legs."""
    b = SceneBuilder(texture_size=16)
    floor = b.material("floor", _checker((180, 140, 90), (120, 90, 60)))
    wall = b.material("wall", _checker((220, 220, 220), (90, 120, 200)))
    b.add_box((0, 0, -0.1), (10, 8, 0), floor)
    b.add_box((0, 0, 2.5), (10, 8, 2.6), wall, tile=0.5)
    for lo, hi in (((0, 0, 0), (10, 0.1, 2.5)), ((0, 7.9, 0), (10, 8, 2.5)),
                   ((0, 0, 0), (0.1, 8, 2.5)), ((9.9, 0, 0), (10, 8, 2.5)),
                   ((5, 0, 0), (5.1, 3, 2.5)), ((5, 4, 0), (5.1, 8, 2.5))):
        b.add_box(lo, hi, wall, tile=0.7)
    for k in range(6):
        b.add_cylinder((1.5 + k, 6.0), 0.05, 0.0, 0.7, wall, segments=8)
    return b.build("two-rooms")


@pytest.fixture(scope="module")
def renderer(room: Scene) -> Renderer:
    return Renderer(room)


def _elevations(spec: CameraSpec) -> np.ndarray:
    h = spec.height
    return np.radians(spec.fov_deg) / 2 * (1 - (2 * np.arange(h) + 1) / h)


def test_depth_to_each_wall_is_exact(renderer: Renderer) -> None:
    spec = renderer.cameras["panorama"]
    out = renderer.render(np.array([[*CAM, 0.0]]), with_ids=True)
    w, h = spec.width, spec.height
    rows = [h // 2 - 1, h // 2]
    cos_el = np.cos(_elevations(spec)[rows])
    for col, dist in ((w // 2, AHEAD), (3 * w // 4, RIGHT), (w // 4, LEFT), (0, BEHIND)):
        np.testing.assert_allclose(out.depth[0, rows, col], dist / cos_el, atol=1e-3)
    # image x runs clockwise: the right-hand wall is blue, the left one yellow
    assert tuple(out.rgb[0, :, h // 2, 3 * w // 4]) == _lit(WALL_COLOURS["right"], (0, 1, 0))
    assert tuple(out.rgb[0, :, h // 2, w // 4]) == _lit(WALL_COLOURS["left"], (0, 1, 0))
    assert out.ids is not None and (out.ids[0] >= 0).all()


def test_floor_below_and_ceiling_above_horizon(renderer: Renderer) -> None:
    out = renderer.render(np.array([[*CAM, 0.3]]))
    h = renderer.cameras["panorama"].height
    floor_z = 0.9 + out.depth[0, -1] * np.sin(_elevations(renderer.cameras["panorama"])[-1])
    ceiling_z = 0.9 + out.depth[0, 0] * np.sin(_elevations(renderer.cameras["panorama"])[0])
    np.testing.assert_allclose(floor_z, 0.0, atol=1e-4)
    np.testing.assert_allclose(ceiling_z, 2.5, atol=1e-4)
    assert h == 128


def _lit(colour: tuple[int, int, int], normal: tuple[float, float, float]) -> tuple[int, ...]:
    light = Lighting().as_array()
    lam = light[0] + light[1] * abs(float(np.dot(normal, light[2:])))
    return tuple(int(np.float32(c) * np.float32(lam) + np.float32(0.5)) for c in colour)


def test_yaw_quarter_turn_rolls_panorama_by_quarter_width(renderer: Renderer) -> None:
    w = renderer.cameras["panorama"].width
    out = renderer.render(np.array([[*CAM, 0.0], [*CAM, np.pi / 2]]), with_ids=True)
    assert out.ids is not None
    rolled = np.roll(out.ids[0], w // 4, axis=-1)
    assert (rolled == out.ids[1]).mean() >= 0.999
    same = rolled == out.ids[1]
    np.testing.assert_allclose(np.roll(out.depth[0], w // 4, axis=-1)[same],
                               out.depth[1][same], atol=1e-4)
    for shift in (w // 4 - 1, w // 4 + 1):  # and not by one column more or less
        assert np.abs(np.roll(out.depth[0], shift, axis=-1) - out.depth[1]).max() > 0.01


def test_pinhole_centre_ray_hits_the_front_wall(renderer: Renderer, room: Scene) -> None:
    spec = renderer.cameras["goal"]
    out = renderer.render(np.array([[*CAM, 0.0]]), camera="goal", with_ids=True)
    assert out.rgb.shape == (1, 3, 128, 128) and out.ids is not None
    i, j = spec.height // 2, spec.width // 2
    f = spec.width / 2 / np.tan(np.radians(spec.fov_deg) / 2)
    d = np.array([f, -0.5, -0.5]) / np.linalg.norm([f, -0.5, -0.5])
    np.testing.assert_allclose(out.depth[0, i, j], AHEAD / d[0], atol=1e-4)
    tri = room.triangles[out.ids[0, i, j]]
    np.testing.assert_allclose(tri[:, 0], CAM[0] + AHEAD)  # the wall's front face
    assert tuple(out.rgb[0, :, i, j]) == _lit(WALL_COLOURS["front"], (1, 0, 0))


def test_repeated_calls_are_bit_identical(textured: Scene) -> None:
    poses = np.array([[2.0, 3.0, 0.4], [7.5, 5.0, -2.0], [5.05, 3.5, 1.6]])
    agents = np.array([[3.0, 3.3], [6.0, 5.0]])
    with Renderer(textured, threads=2, chunk_rays=5000) as two, \
            Renderer(textured, threads=1) as one:
        a = two.render(poses, agents=agents, with_ids=True)
        b = two.render(poses, agents=agents, with_ids=True)
        c = one.render(poses, agents=agents, with_ids=True)
    for x in (b, c):
        assert np.array_equal(a.rgb, x.rgb) and np.array_equal(a.depth, x.depth)
        assert a.ids is not None and np.array_equal(a.ids, x.ids)


def test_other_agents_visible_own_body_not(renderer: Renderer) -> None:
    spec = renderer.cameras["panorama"]
    agents = np.array([[*CAM], [CAM[0] + 1.5, CAM[1]]])  # agent 1 stands 1.5 m ahead
    poses = np.array([[*CAM, 0.0], [*agents[1], np.pi]])
    out = renderer.render(poses, agents=agents, exclude=np.array([0, 1]), with_ids=True)
    assert out.ids is not None
    assert not (out.ids[0] == -2).any() and not (out.ids[1] == -3).any()
    el = _elevations(spec)
    row = int(np.argmin(np.abs(el - np.radians(-20.0))))
    col = spec.width // 2
    assert out.ids[0, row, col] == -3 and out.ids[1, row, col] == -2
    np.testing.assert_allclose(out.depth[0, row, col], (1.5 - 0.18) / np.cos(el[row]), atol=1e-4)
    expected = _lit(tuple(int(c) for c in BODY_PALETTE[1]), (-1, 0, 0))
    assert tuple(out.rgb[0, :, row, col]) == expected
    # per-view bodies (B, A, 2): the second view sees nobody
    per_view = np.stack([agents, np.full((2, 2), 50.0)])
    out2 = renderer.render(poses, agents=per_view, with_ids=True)
    assert out2.ids is not None and (out2.ids[0] == -3).any() and (out2.ids[1] >= -1).all()


def test_image_sizes_are_configurable(room: Scene) -> None:
    with Renderer(room, panorama=CameraSpec.panorama(128, 32), threads=1) as r:
        out = r.render(np.array([[*CAM, 0.0], [*CAM, 1.0]]))
    assert out.rgb.shape == (2, 3, 32, 128) and out.rgb.dtype == np.uint8
    assert out.depth.shape == (2, 32, 128) and out.depth.dtype == np.float32 and out.ids is None
    np.testing.assert_allclose(out.depth[0, 15:17, 64], AHEAD / np.cos(np.radians(45 / 32)),
                               atol=1e-3)


@pytest.mark.parametrize(("poses", "kwargs", "match"), [
    (np.array([[1.0, np.nan, 0.0]]), {}, "NaN"),
    (np.zeros((0, 3)), {}, "empty batch"),
    (np.zeros((2, 2)), {}, r"shape \(B, 3\)"),
    (np.zeros(3), {}, r"shape \(B, 3\)"),
    (np.zeros((1, 3)), {"camera": "fisheye"}, "unknown camera"),
    (np.zeros((1, 3)), {"agents": np.zeros((2, 3))}, "agents must have shape"),
    (np.zeros((1, 3)), {"agents": np.zeros((2, 2)), "exclude": np.array([2])}, "exclude"),
    (np.zeros((1, 3)), {"exclude": np.array([0.5])}, "exclude"),
])
def test_bad_render_input_is_rejected(renderer: Renderer, poses: np.ndarray, kwargs: dict,
                                      match: str) -> None:
    with pytest.raises(RenderError, match=match):
        renderer.render(poses, **kwargs)


def test_bad_backend_device_and_camera(room: Scene, monkeypatch: pytest.MonkeyPatch) -> None:
    with pytest.raises(RenderError, match="unknown render backend"):
        Renderer(room, backend="opengl")  # type: ignore[arg-type]
    with pytest.raises(RenderError, match="CPU only"):
        Renderer(room, device="cuda:0")
    with pytest.raises(RenderError, match="multiple of 4"):
        CameraSpec.panorama(510, 128)
    with pytest.raises(RenderError, match="field of view"):
        CameraSpec.pinhole(fov_deg=180)
    with pytest.raises(RenderError, match="threads"):
        Renderer(room, threads=0)
    monkeypatch.setitem(sys.modules, "warp", None)
    monkeypatch.setitem(sys.modules, "collavn.rendering.warp_backend", None)
    with pytest.raises(RenderError, match="pip install warp-lang"):
        Renderer(room, backend="warp")


def test_gpu_requested_without_gpu(room: Scene) -> None:
    wp = pytest.importorskip("warp")
    if wp.get_cuda_device_count() > 0:
        pytest.skip("this machine has a CUDA GPU")
    with pytest.raises(RenderError, match="finds 0 CUDA"):
        Renderer(room, backend="warp", device="cuda:0")
    with pytest.raises(RenderError, match="unknown device"):
        Renderer(room, backend="warp", device="tpu")


def test_warp_and_embree_agree(textured: Scene) -> None:
    pytest.importorskip("warp")
    rng = np.random.default_rng(0)
    poses = np.column_stack([rng.uniform(0.4, 9.6, 12), rng.uniform(0.4, 7.6, 12),
                             rng.uniform(-np.pi, np.pi, 12)])
    agents = np.array([[3.0, 3.3], [6.0, 5.0], [2.0, 1.0]])
    exclude = rng.integers(-1, 3, 12)
    embree = Renderer(textured, panorama=CameraSpec.panorama(256, 64))
    warp = Renderer(textured, backend="warp", panorama=CameraSpec.panorama(256, 64))
    for camera in ("panorama", "goal"):
        a = embree.render(poses, camera, agents=agents, exclude=exclude, with_ids=True)
        b = warp.render(poses, camera, agents=agents, exclude=exclude, with_ids=True)
        assert a.ids is not None and b.ids is not None
        same = a.ids == b.ids
        assert same.mean() >= 0.999
        assert (a.ids < -1).any() and (a.ids >= 0).any()
        # colours agree exactly except where float rounding of the barycentrics moves
        # a hit across a texel border (a handful of pixels in a million)
        assert (a.rgb == b.rgb).all(axis=1)[same].mean() >= 0.9995
        np.testing.assert_allclose(a.depth[same], b.depth[same], rtol=1e-5, atol=1e-5)
    embree.close()


def test_render_command_writes_image_and_depth(tmp_path, monkeypatch: pytest.MonkeyPatch) -> None:
    from PIL import Image

    from collavn.cli.render import RenderCommand, parse_pose

    monkeypatch.setenv("COLLAVN_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "pano.png"
    assert RenderCommand("procedural:0", out=out, width=128, height=32).run() == 0
    assert Image.open(out).size == (128, 32)
    depth = np.asarray(Image.open(tmp_path / "pano_depth.png"))
    assert depth.shape == (32, 128) and depth.max() > depth.min()
    goal = tmp_path / "goal.png"
    assert RenderCommand("procedural:0", out=goal, pose="3,3,90", goal=True).run() == 0
    assert Image.open(goal).size == (128, 128)
    np.testing.assert_allclose(parse_pose("1,2,90"), [1, 2, np.pi / 2])
    with pytest.raises(RenderError, match="X,Y,YAW"):
        parse_pose("1,2")
