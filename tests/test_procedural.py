"""Procedural apartments: determinism, layout, navigability, looks, splits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from collavn.errors import SceneError
from collavn.scenes import load_scene
from collavn.scenes import textures as tx
from collavn.scenes.floorplan import WALL_THICKNESS, FloorPlan, Rect, plan_apartment
from collavn.scenes.procedural import WALL_HEIGHT, apartment_plan, generate_apartment
from collavn.scenes.scene import Scene
from collavn.scenes.splits import SPLITS, scene_specs, split_seeds

SEEDS = (0, 7, 11)  # 12 rooms + hall; 6 small rooms; a 23.5 × 18.8 m apartment


@pytest.fixture(scope="module")
def built() -> dict[int, tuple[Scene, FloorPlan]]:
    return {s: (generate_apartment(s), apartment_plan(s)) for s in SEEDS}


def _room_points(scene: Scene, rect: Rect) -> np.ndarray:
    """Centres of the largest component's cells inside ``rect``: ``(K, 2)``."""
    nav = scene.nav
    rows, cols = np.nonzero(nav.components == 1)
    pts = nav.cell_centers(rows, cols)
    inside = ((pts[:, 0] > rect.x0) & (pts[:, 0] < rect.x1)
              & (pts[:, 1] > rect.y0) & (pts[:, 1] < rect.y1))
    return pts[inside]


# ------------------------------------------------------------- determinism
def test_same_seed_same_scene_and_different_seeds_differ(built) -> None:
    scene, _ = built[7]
    again = generate_apartment(7)
    assert again.content_hash == scene.content_hash
    assert again.name == again.source == "procedural:7"
    assert built[0][0].content_hash != scene.content_hash


def test_load_scene_spec_builds_the_same_apartment(built, tmp_path) -> None:
    scene = load_scene("procedural:7", cache_dir=tmp_path)
    assert scene.content_hash == built[7][0].content_hash


def test_negative_seed_is_rejected() -> None:
    with pytest.raises(SceneError, match="seed"):
        generate_apartment(-1)


# ------------------------------------------------------------------ layout
def test_footprint_and_room_count_ranges() -> None:
    widths = []
    for seed in range(40):
        plan = apartment_plan(seed)
        fp = plan.footprint
        assert 10.0 <= fp.width <= 30.0 and 10.0 <= fp.height <= 30.0
        assert 4 <= sum(r.kind != "hall" for r in plan.rooms) <= 12
        widths.append(max(fp.width, fp.height))
    assert max(widths) - min(widths) > 8.0  # small flats and large houses both occur


def test_room_count_options_are_respected() -> None:
    for seed in range(10):
        rooms = apartment_plan(seed, min_rooms=5, max_rooms=6).rooms
        assert 5 <= sum(r.kind != "hall" for r in rooms) <= 6
    with pytest.raises(SceneError, match="room range"):
        apartment_plan(0, min_rooms=8, max_rooms=4)


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
def test_plan_invariants(seed: int) -> None:
    plan = plan_apartment(np.random.default_rng(seed))
    fp = plan.footprint
    # Rooms tile the footprint: inside it, no overlaps, areas add up.
    assert all(fp.contains(r.rect) for r in plan.rooms)
    assert sum(r.rect.area for r in plan.rooms) == pytest.approx(fp.area)
    for i, a in enumerate(plan.rooms):
        for b in plan.rooms[i + 1:]:
            assert not a.rect.shrink(1e-6).near(b.rect.shrink(1e-6))
    # Doors: wide enough, on the wall both rooms share, every room reachable.
    reached, frontier = {0}, [0]
    for door in plan.doors:
        assert door.width >= 0.9
        for k in (door.a, door.b):
            r = plan.rooms[k].rect
            lo, hi = (r.y0, r.y1) if door.axis == 0 else (r.x0, r.x1)
            assert lo < door.lo < door.hi < hi
            assert door.at in ((r.x0, r.x1) if door.axis == 0 else (r.y0, r.y1))
    while frontier:
        k = frontier.pop()
        for d in plan.doors_of(k):
            other = d.b if d.a == k else d.a
            if other not in reached:
                reached.add(other)
                frontier.append(other)
    assert reached == set(range(len(plan.rooms)))


# ------------------------------------------------------------ navigability
@pytest.mark.parametrize("seed", SEEDS)
def test_apartment_is_one_connected_region(built, seed: int) -> None:
    scene, plan = built[seed]
    sizes = scene.nav.component_sizes()
    assert sizes[0] >= 0.9 * sizes.sum()
    for room in plan.rooms:
        interior = room.rect.shrink(WALL_THICKNESS / 2)
        inside = _room_points(scene, interior)
        assert len(inside) * scene.nav.resolution**2 >= 0.3 * interior.area, room


@pytest.mark.parametrize("seed", SEEDS)
def test_every_room_reachable_by_geodesic_path(built, seed: int) -> None:
    scene, plan = built[seed]
    anchors = []
    for room in plan.rooms:
        pts = _room_points(scene, room.rect)
        anchors.append(pts[np.argmin(np.linalg.norm(pts - room.rect.center, axis=1))])
    field = scene.geodesic_field(anchors[0])
    dist = field.distance(np.array(anchors))
    assert np.isfinite(dist).all()
    path = scene.shortest_path(anchors[-1], anchors[0])
    assert np.allclose(path[-1], anchors[0]) and len(path) > 2


@pytest.mark.parametrize("seed", SEEDS)
def test_doors_are_passable_and_kept_clear(built, seed: int) -> None:
    scene, plan = built[seed]
    for door in plan.doors:
        normal = np.array([1.0, 0.0]) if door.axis == 0 else np.array([0.0, 1.0])
        centre = np.array(door.center)
        points = centre + np.outer([-0.5, 0.0, 0.5], normal)  # through the doorway
        assert scene.nav.is_navigable(points).all(), door
        assert (scene.nav.component_at(points) == 1).all(), door


# ------------------------------------------------------------------- looks
def test_materials_are_moderate_and_well_formed(built) -> None:
    for scene, _ in built.values():
        m, s = len(scene.textures), scene.textures.shape[1]
        assert scene.textures.shape == (m, s, s, 3) and s == 64
        assert scene.textures.dtype == np.uint8 and 20 <= m < 64
        assert len(np.unique(scene.face_material)) >= m - 6  # few unused furniture materials
        assert 500 < scene.num_triangles < 6000
    small = generate_apartment(1, texture_size=16)
    assert small.textures.shape[1:] == (16, 16, 3)


def _room_surface_materials(scene: Scene, rect: Rect) -> tuple[set[int], set[int]]:
    """Materials of the floor slab and of the full-height walls inside ``rect``."""
    tri = scene.triangles
    centre = tri.mean(axis=1)
    n = scene.face_normals
    h = WALL_THICKNESS / 2 + 1e-3
    inside = ((centre[:, 0] > rect.x0 - 1e-3) & (centre[:, 0] < rect.x1 + 1e-3)
              & (centre[:, 1] > rect.y0 - 1e-3) & (centre[:, 1] < rect.y1 + 1e-3))
    floor = inside & (np.abs(tri[:, :, 2]).max(axis=1) < 1e-6) & (n[:, 2] > 0.9)
    near_border = ((np.abs(centre[:, 0] - rect.x0) < h) | (np.abs(centre[:, 0] - rect.x1) < h)
                   | (np.abs(centre[:, 1] - rect.y0) < h) | (np.abs(centre[:, 1] - rect.y1) < h))
    z = tri[:, :, 2]
    full_height = (z.min(axis=1) < 1e-6) & (z.max(axis=1) > WALL_HEIGHT - 1e-3)
    inner = rect.shrink(WALL_THICKNESS / 2)
    facing_in = ((centre[:, :2] - inner.center) * n[:, :2]).sum(axis=1) < 0
    wall = inside & near_border & full_height & (np.abs(n[:, 2]) < 0.1) & facing_in
    return set(scene.face_material[floor].tolist()), set(scene.face_material[wall].tolist())


@pytest.mark.parametrize("seed", SEEDS)
def test_each_room_has_its_own_floor_and_walls(built, seed: int) -> None:
    scene, plan = built[seed]
    floors, walls = [], []
    for room in plan.rooms:
        f, w = _room_surface_materials(scene, room.rect)
        assert len(f) == 1 and len(w) == 1, (room, f, w)
        floors += f
        walls += w
    assert len(set(floors)) == len(floors) and len(set(walls)) == len(walls)
    textures = scene.textures[floors + walls].reshape(len(floors) + len(walls), -1)
    assert len(np.unique(textures, axis=0)) == len(textures)  # not just renamed copies


SURFACES = (tx.plaster, tx.wood, tx.wood_floor, tx.tiles, tx.carpet, tx.fabric, tx.marble,
            tx.brick, tx.stripes, tx.dots, tx.damask, tx.checks)


@pytest.mark.parametrize("fn", [*SURFACES, tx.abstract_painting, tx.landscape_painting,
                                tx.book_spines], ids=lambda f: f.__name__)
def test_texture_generators_are_deterministic_images(fn) -> None:
    a = fn(np.random.default_rng(5), 64)
    assert a.shape == (64, 64, 3) and a.dtype == np.uint8
    assert np.array_equal(a, fn(np.random.default_rng(5), 64))
    assert not np.array_equal(a, fn(np.random.default_rng(6), 64))
    assert a.astype(float).std() > 1.0  # not a flat colour


def _seam_excess(t: np.ndarray) -> float:
    """How much the wrap-around jump exceeds the largest jump between inner rows/columns.

    ``<= 0`` for a seamless texture (a pattern edge may fall on the seam).
    """
    t = t.astype(float)
    excess = []
    for axis in (0, 1):
        inner = np.abs(np.diff(t, axis=axis)).mean(axis=(1 - axis, 2))
        seam = np.abs(t.take(0, axis=axis) - t.take(-1, axis=axis)).mean()
        excess.append(seam - inner.max())
    return max(excess)


@pytest.mark.parametrize("fn", SURFACES, ids=lambda f: f.__name__)
def test_surface_textures_tile_seamlessly(fn) -> None:
    for seed in range(3):
        assert _seam_excess(fn(np.random.default_rng(seed), 64)) <= 1.0
    ramp = np.broadcast_to(np.linspace(0, 255, 64)[:, None, None], (64, 64, 3))
    assert _seam_excess(ramp) > 100  # the check does see a real seam


# ------------------------------------------------------------------ splits
def test_default_splits_match_the_paper_and_are_disjoint() -> None:
    seeds = {s: split_seeds(s) for s in SPLITS}
    assert [len(seeds[s]) for s in SPLITS] == [25, 5, 5]
    assert seeds["train"] == list(range(25))
    assert not set(seeds["train"]) & set(seeds["val"])
    assert not set(seeds["val"]) & set(seeds["test"])
    assert not set(seeds["train"]) & set(seeds["test"])
    big = {s: set(split_seeds(s, sizes=(1000, 1000, 1000))) for s in SPLITS}
    assert len(big["train"] | big["val"] | big["test"]) == 3000


def test_scene_specs_and_unknown_split() -> None:
    assert scene_specs("val")[:2] == ["procedural:1000", "procedural:1001"]
    assert len(scene_specs("test", sizes=(1, 2, 3))) == 3
    with pytest.raises(SceneError, match="unknown split"):
        split_seeds("validation")
    with pytest.raises(SceneError, match="size"):
        split_seeds("train", sizes=(5000, 5, 5))
