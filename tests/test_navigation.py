import math

import numpy as np
import pytest

from collavn.errors import SceneError
from collavn.scenes.builder import SceneBuilder, flat_texture
from collavn.scenes.navigation import NavConfig

RES = NavConfig().resolution
# Obstacle surfaces are rasterised to 10 cm cells before erosion by the robot radius:
# the effective clearance around a corner is the radius plus about one cell.
RHO = NavConfig().agent_radius + RES


def around_corner(a, g, c, rho):
    """Shortest path from a to g around a convex corner at c rounded to radius rho.

    Tangent segments plus the arc on the free side of the corner (the obstacle fills
    the angle between a - c and g - c, so the path goes the long way round the disk).
    """
    a, g, c = (np.asarray(v, dtype=float) for v in (a, g, c))
    da, dg = np.linalg.norm(a - c), np.linalg.norm(g - c)
    ta, tg = math.sqrt(da**2 - rho**2), math.sqrt(dg**2 - rho**2)
    angle = 2 * math.pi - math.acos(np.dot(a - c, g - c) / (da * dg))
    arc = angle - math.acos(rho / da) - math.acos(rho / dg)
    return ta + tg + rho * max(arc, 0.0)


def test_l_corridor_matches_the_analytic_shortest_path(l_corridor):
    a, g = (9.0, 1.0), (1.0, 9.0)
    expected = around_corner(a, g, (2.0, 2.0), RHO)
    assert l_corridor.geodesic_distance(a, g) == pytest.approx(expected, abs=RES)
    # and it is clearly longer than the straight line through the block
    assert l_corridor.geodesic_distance(a, g) > math.dist(a, g) + 2.5


def test_door_path_goes_through_the_door(door_scene):
    a, g = (2.0, 1.0), (8.0, 1.0)
    # around the lower door jamb: corners at (5, 3) and (5.1, 3), inflated by RHO
    p1, p2 = np.array([5.0, 3.0 + RHO]), np.array([5.1, 3.0 + RHO])
    polygonal = np.linalg.norm(p1 - a) + np.linalg.norm(p2 - p1) + np.linalg.norm(g - p2)
    d = door_scene.geodesic_distance(a, g)
    assert d == pytest.approx(polygonal, abs=RES)
    path = door_scene.shortest_path(a, g)
    crossing = path[np.argmin(np.abs(path[:, 0] - 5.05))]
    assert 3.0 < crossing[1] < 4.0


def test_geodesic_is_symmetric_and_never_shorter_than_euclid(door_scene, l_corridor):
    rng = np.random.default_rng(0)
    for scene in (door_scene, l_corridor):
        rows, cols = np.nonzero(scene.nav.components == 1)
        pick = rng.choice(len(rows), size=(12, 2))
        for i, j in pick:
            a = scene.nav.cell_centers(rows[i], cols[i])
            b = scene.nav.cell_centers(rows[j], cols[j])
            dab, dba = scene.geodesic_distance(a, b), scene.geodesic_distance(b, a)
            assert dab == pytest.approx(dba, abs=RES)
            assert dab >= np.linalg.norm(a - b) - 0.02


def test_shortest_path_is_navigable_and_as_long_as_the_geodesic(door_scene):
    a, g = np.array([2.0, 5.0]), np.array([8.0, 0.8])
    path = door_scene.shortest_path(a, g)
    assert door_scene.nav.is_navigable(path).all()
    length = np.linalg.norm(np.diff(path, axis=0), axis=1).sum()
    d = door_scene.geodesic_distance(a, g)
    assert d - RES <= length <= d * 1.1 + RES  # 8-connected steps: at most ~8 % longer


def test_unreachable_goal_is_infinite():
    b = SceneBuilder(8)
    m = b.material("m", flat_texture((100, 100, 100), 8))
    b.add_box((0, 0, -0.1), (10, 4, 0), m)
    b.add_box((5, 0, 0), (5.1, 4, 2.5), m)  # a full wall: two rooms, no door
    scene = b.build("two-rooms")
    assert scene.nav.components.max() == 2
    assert scene.geodesic_distance((2, 2), (8, 2)) == math.inf
    with pytest.raises(SceneError, match="cannot reach"):
        scene.shortest_path((2, 2), (8, 2))
    with pytest.raises(SceneError, match="not on navigable floor"):
        scene.geodesic_distance((2, 2), (5.05, 2))


def test_navigable_cells_keep_the_robot_radius_from_walls(door_scene):
    nav = door_scene.nav
    rows, cols = np.nonzero(nav.navigable)
    centres = nav.cell_centers(rows, cols)
    # the wall occupies x ∈ [5, 5.1] except the door
    in_wall_rows = (centres[:, 1] < 3) | (centres[:, 1] > 4)
    gap = np.abs(centres[:, 0] - 5.05) - 0.05
    assert (gap[in_wall_rows] >= NavConfig().agent_radius).all()


def test_inside_of_a_solid_block_is_not_floor(l_corridor):
    assert not l_corridor.nav.is_navigable(np.array([[6.0, 6.0]]))[0]
    assert l_corridor.nav.components.max() == 1


def test_table_blocks_but_thin_legs_are_found():
    b = SceneBuilder(8)
    m = b.material("m", flat_texture((100, 100, 100), 8))
    b.add_box((0, 0, -0.1), (6, 6, 0), m)
    b.add_box((2, 2, 0.72), (3, 3, 0.75), m)  # a table top under the robot's height
    b.add_cylinder((4.5, 4.5), 0.025, 0.0, 0.7, m)  # a lone 5 cm leg
    scene = b.build("table")
    assert not scene.nav.free[scene.nav.to_cell(np.array([2.5, 2.5]))]
    assert not scene.nav.free[scene.nav.to_cell(np.array([4.5, 4.5]))]
    assert scene.nav.is_navigable(np.array([[1.0, 1.0]]))[0]


def test_no_navigable_area_is_a_clear_error():
    b = SceneBuilder(8)
    m = b.material("m", flat_texture((100, 100, 100), 8))
    b.add_box((0, 0, -0.1), (0.3, 0.3, 0), m)  # smaller than the robot
    with pytest.raises(SceneError, match="no navigable area"):
        b.build("tiny")


def test_no_floor_at_height_is_a_clear_error():
    b = SceneBuilder(8)
    m = b.material("m", flat_texture((100, 100, 100), 8))
    b.add_box((0, 0, -0.1), (5, 5, 0), m)
    with pytest.raises(SceneError, match=r"no floor surface at height z=3.00"):
        b.build("floor", floor_z=3.0)


def test_blocked_field_detours_and_paths_start_next_to_a_blocked_cell(door_scene):
    nav = door_scene.nav
    a, g = np.array([2.0, 3.5]), np.array([8.0, 3.5])  # straight through the door
    robot = np.array([5.05, 3.5])  # a robot standing in the doorway
    blocked = nav.discs(robot[None], 0.36)
    assert blocked[nav.to_cell(robot)] and not blocked[nav.to_cell(a)]
    free_field = nav.geodesic_field(g)
    assert not np.isfinite(nav.geodesic_field(g, blocked=blocked).distance(a[None])[0])
    assert np.isfinite(free_field.distance(a[None])[0])  # the door is the only way
    # a start whose own cell is blocked begins at its best free neighbour
    own = np.zeros(nav.shape, dtype=bool)
    own[nav.to_cell(a)] = True
    beside = nav.geodesic_field(g, blocked=own)
    assert not np.isfinite(beside.grid[nav.to_cell(a)])
    path = beside.path_from(a)
    assert np.isfinite(beside.grid[nav.to_cell(path[1])])
    np.testing.assert_allclose(path[-1], g)


def test_a_goal_walled_in_by_robots_gets_a_field_not_a_crash(door_scene):
    """Robots' discs around a goal leave it a pocket with no zero contour to march from.

    (A DAgger run crashed here: skfmm raised "no zero contour" from the oracle's detour.)
    """
    nav = door_scene.nav
    g = nav.cell_centers(*nav.to_cell(np.array([2.0, 3.5])))  # a cell centre
    r, c = nav.to_cell(g)
    blocked = np.zeros(nav.shape, dtype=bool)
    blocked[r - 1:r + 2, c - 1:c + 2] = True
    blocked[r, c] = False  # the goal's own cell, walled in; the rest of the room is free
    assert (nav.components[~blocked] == nav.components[r, c]).sum() > 100
    field = nav.geodesic_field(g, blocked=blocked)
    assert field.grid[r, c] == pytest.approx(0.0, abs=1e-9)
    assert np.isfinite(field.grid).sum() == 1
    blocked[:] = True
    # a pocket of three cells with two more cells beyond a diagonal gap: fast marching
    # cannot step diagonally, so those stay unreachable
    blocked[r - 1:r + 2, c] = False
    blocked[r + 2:r + 4, c + 1] = False
    field = nav.geodesic_field(g, blocked=blocked)
    finite = np.isfinite(field.grid)
    assert finite[r - 1:r + 2, c].all() and finite.sum() == 3
    np.testing.assert_allclose(field.grid[r - 1:r + 2, c], [RES, 0.0, RES], atol=0.02 * RES)


def _distance_as_arrays(field, xy):
    """The array form the compiled ``GeodesicField.distance`` replaced (the reference)."""
    nav = field.nav
    xy = np.asarray(xy, dtype=np.float64)
    fx = (xy[..., 0] - nav.origin[0]) / nav.resolution - 0.5
    fy = (xy[..., 1] - nav.origin[1]) / nav.resolution - 0.5
    with np.errstate(invalid="ignore"):
        c0, r0 = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    h, w = nav.shape
    best = np.full(xy.shape[:-1], np.inf)
    for dr in (0, 1):
        for dc in (0, 1):
            r, c = r0 + dr, c0 + dc
            ok = (r >= 0) & (r < h) & (c >= 0) & (c < w)
            d = np.full(best.shape, np.inf)
            d[ok] = field.grid[r[ok], c[ok]]
            best = np.minimum(best, d + np.linalg.norm(xy - nav.cell_centers(r, c), axis=-1))
    near = np.linalg.norm(xy - field.goal, axis=-1)
    best = np.where(near <= nav.resolution, np.minimum(best, near), best)
    return np.maximum(best, near)


def test_the_compiled_distance_is_bit_equal_to_the_array_form(door_scene):
    nav = door_scene.nav
    field = door_scene.geodesic_field((8.0, 3.5))
    rng = np.random.default_rng(0)
    lo = nav.origin - 1.0
    hi = nav.origin + np.array(nav.shape[::-1]) * nav.resolution + 1.0
    pts = rng.uniform(lo, hi, size=(4000, 2))  # inside, outside, walls, unreachable
    pts[:50] = field.goal + rng.normal(0, nav.resolution, (50, 2))  # the goal's cell
    pts[50:60] = nav.cell_centers(*nav.to_cell(pts[50:60]))  # exactly on cell centres
    got, ref = field.distance(pts), _distance_as_arrays(field, pts)
    assert np.isfinite(ref).sum() > 1000 and np.isinf(ref).sum() > 100
    assert np.array_equal(got, ref)  # bit for bit, inf included
    assert field.distance(pts.reshape(40, 100, 2)).shape == (40, 100)
    assert np.array_equal(field.distance(pts.reshape(40, 100, 2)), ref.reshape(40, 100))
    odd = np.array([[np.nan, 3.0], [np.inf, 3.0], [2.0, -np.inf]])
    with np.errstate(invalid="ignore"):
        odd_ref = _distance_as_arrays(field, odd)
    np.testing.assert_array_equal(field.distance(odd), odd_ref)  # nan, inf, inf
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\) points, got shape \(4, 3\)"):
        field.distance(np.zeros((4, 3)))  # not silently read as six 2-D points
