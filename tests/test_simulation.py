import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from collavn.errors import ActionError
from collavn.simulation.kinematics import AgentParams, drive, overlapping
from collavn.simulation.world import World, check_actions, relative_pose
from collavn.tasks import get_task, step_world

P = AgentParams()


def _drive(scene, pos, yaw, act):
    pos, yaw, act = (np.asarray(v, dtype=float)[None] for v in (pos, yaw, act))
    return drive(scene.nav, pos, yaw, act, np.ones(yaw.shape, bool), P)


def test_full_speed_straight_covers_0_70_m(open_room):
    r = _drive(open_room, [[2.0, 4.0]], [0.3], [[1.0, 0.0]])
    moved = r.position[0, 0] - [2.0, 4.0]
    assert np.linalg.norm(moved) == pytest.approx(0.70, abs=1e-9)
    assert np.arctan2(moved[1], moved[0]) == pytest.approx(0.3)
    assert r.distance[0, 0] == pytest.approx(0.70)
    assert not r.collided.any()


def test_full_speed_turn_rotates_180_degrees(open_room):
    r = _drive(open_room, [[4.0, 4.0]], [0.0], [[0.0, 1.0]])
    assert abs(r.yaw[0, 0]) == pytest.approx(np.pi)
    np.testing.assert_allclose(r.position[0, 0], [4.0, 4.0])


def test_arc_ends_where_the_unicycle_model_says(open_room):
    # v = 0.35 m/s, w = π/2 rad/s for 1 s: a quarter circle of radius 2·0.35/π
    r = _drive(open_room, [[4.0, 4.0]], [0.0], [[0.5, 0.5]])
    radius = 0.35 / (np.pi / 2)
    np.testing.assert_allclose(r.position[0, 0], [4.0 + radius, 4.0 + radius], atol=2e-3)


def test_wall_stops_the_robot_without_tunnelling(door_scene):
    r = _drive(door_scene, [[4.7, 1.0]], [0.0], [[1.0, 0.0]])
    assert r.collided[0, 0]
    assert r.position[0, 0, 0] < 5.0 - P.radius
    assert r.distance[0, 0] < 0.7


def test_agents_block_each_other(open_room):
    r = _drive(open_room, [[3.0, 4.0], [3.6, 4.0]], [0.0, np.pi], [[1, 0], [1, 0]])
    assert r.collided.all()
    assert np.linalg.norm(r.position[0, 0] - r.position[0, 1]) >= 2 * P.radius


@settings(max_examples=25, deadline=None)
@given(st.lists(st.tuples(st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1),
                          st.floats(-1, 1), st.floats(-1, 1), st.floats(-1, 1)),
                min_size=1, max_size=12))
def test_no_agent_ever_ends_in_an_obstacle_or_another_agent(door_scene, actions):
    pos = np.array([[[4.4, 1.0], [4.5, 3.5], [5.6, 3.4]]])
    yaw = np.zeros((1, 3))
    for a in actions:
        act = np.array(a).reshape(1, 3, 2)
        r = drive(door_scene.nav, pos, yaw, act, np.ones((1, 3), bool), P)
        pos, yaw = r.position, r.yaw
        assert door_scene.nav.is_navigable(pos).all()
        assert not overlapping(pos, P.radius).any()


def test_actions_are_validated():
    with pytest.raises(ActionError, match="shape"):
        check_actions(np.zeros((1, 2, 3)), 1, 2)
    bad = np.zeros((2, 2, 2))
    bad[1, 0, 1] = np.nan
    with pytest.raises(ActionError, match="agent_0 in env 1"):
        check_actions(bad, 2, 2)
    np.testing.assert_array_equal(check_actions(np.full((1, 1, 2), 3.0), 1, 1), 1.0)


def test_relative_pose_in_start_frame():
    frame = np.array([1.0, 1.0, np.pi / 2])
    pose = np.array([1.0, 2.0, np.pi])
    np.testing.assert_allclose(relative_pose(frame, pose), [1.0, 0.0, np.pi / 2], atol=1e-12)


def _episode(scene, starts, goal, yaws=None):
    from collavn.datasets.episode import Episode, SceneRef

    starts = np.asarray(starts, dtype=float)
    n = len(starts)
    return Episode(
        episode_id="hand-0", scene=SceneRef(scene.name, scene.source, scene.content_hash),
        task="commongoal", difficulty="medium", start_positions=starts,
        start_yaws=np.zeros(n) if yaws is None else np.asarray(yaws, float),
        goal_positions=np.asarray([goal], float), goal_yaws=np.zeros(1),
        goal_index=np.zeros(n, np.int64),
        start_distances=np.array([scene.geodesic_distance(s, goal) for s in starts]))


def test_reward_is_geodesic_progress_minus_collision_penalty(open_room, door_scene):
    task = get_task("commongoal")
    world = World(open_room, 1, 1)
    world.reset_envs([0], [_episode(open_room, [[1.0, 4.0]], (6.0, 4.0))])
    out = step_world(world, np.array([[[1.0, 0.0]]]), task)
    assert out.reward[0, 0] == pytest.approx(0.70, abs=1e-6)  # straight line = geodesic
    # driving into the wall: no progress, one collision
    world = World(door_scene, 1, 1)
    world.reset_envs([0], [_episode(door_scene, [[4.75, 1.0]], (2.0, 1.0), yaws=[0.0])])
    d0 = world.distance[0, 0]
    out = step_world(world, np.array([[[1.0, 0.0]]]), task)
    assert out.collided[0, 0]
    assert out.reward[0, 0] == pytest.approx(d0 - world.distance[0, 0] - 0.05, abs=1e-9)
    assert world.collisions[0, 0] == 1


def test_success_terminates_and_time_limit_truncates(open_room):
    from dataclasses import replace

    task = replace(get_task("commongoal"), max_steps=3)
    world = World(open_room, 1, 2)
    world.reset_envs([0], [_episode(open_room, [[2.0, 2.0], [2.0, 6.0]], (3.8, 2.0))])
    out = step_world(world, np.array([[[1.0, 0.0], [0.0, 0.0]]]), task)  # 1.8 → 1.1 m: not yet
    assert not out.terminated.any()
    out = step_world(world, np.array([[[1.0, 0.0], [0.0, 0.0]]]), task)  # 1.1 → 0.4 m: success
    assert out.terminated[0, 0] and not out.truncated[0, 0]
    assert world.success[0, 0] and not world.running[0, 0]
    out = step_world(world, np.array([[[1.0, 0.0], [0.0, 0.0]]]), task)
    assert out.truncated[0, 1] and not out.terminated[0, 1]  # step 3 = T
    assert out.reward[0, 0] == 0.0  # finished agents earn nothing and stay put
    np.testing.assert_allclose(world.position[0, 0], [3.4, 2.0])
    assert world.steps[0].tolist() == [2, 3]
    assert world.path_length[0, 0] == pytest.approx(1.4)


def test_success_reward_is_paid_once_on_arrival(open_room):
    from dataclasses import replace

    from collavn.envs.config import EnvConfig
    from collavn.errors import ConfigError

    task = replace(get_task("commongoal"), success_reward=2.5)
    world = World(open_room, 1, 2)
    world.reset_envs([0], [_episode(open_room, [[2.0, 2.0], [2.0, 6.0]], (3.8, 2.0))])
    out = step_world(world, np.array([[[1.0, 0.0], [0.0, 0.0]]]), task)  # 1.8 → 1.1 m
    assert out.reward[0, 0] == pytest.approx(0.70, abs=1e-6)  # no bonus before arriving
    d0 = world.distance[0, 0]
    out = step_world(world, np.array([[[1.0, 0.0], [1.0, 0.0]]]), task)  # 1.1 → 0.4 m
    assert out.terminated[0, 0] and not out.terminated[0, 1]
    assert out.reward[0, 0] == pytest.approx(d0 - world.distance[0, 0] + 2.5, abs=1e-9)
    assert out.reward[0, 1] < 1.0  # the agent still on its way gets no bonus
    out = step_world(world, np.array([[[1.0, 0.0], [0.0, 0.0]]]), task)
    assert out.reward[0, 0] == 0.0  # paid once: a finished agent earns nothing more
    with pytest.raises(ConfigError, match=r"--env\.success-reward"):
        EnvConfig(success_reward=float("nan"))
    with pytest.raises(ConfigError, match=r"--env\.success-reward"):
        EnvConfig(success_reward=-1.0)
