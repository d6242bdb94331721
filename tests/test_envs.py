import numpy as np
import pytest
from pettingzoo.test import parallel_api_test, parallel_seed_test

from collavn.envs import EnvConfig, VectorEnv, make_parallel_env
from collavn.errors import ActionError
from collavn.metrics import AgentRecord

SMALL = {"panorama_width": 64, "panorama_height": 16, "goal_size": 16, "difficulty": "easy",
         "max_steps": 12}


def test_pettingzoo_parallel_api(open_room):
    env = make_parallel_env(open_room, num_agents=3, **SMALL)
    parallel_api_test(env, num_cycles=30)


def test_pettingzoo_parallel_seed(open_room):
    parallel_seed_test(lambda: make_parallel_env(open_room, num_agents=2, **SMALL))


def test_parallel_env_observations_and_render(open_room):
    env = make_parallel_env(open_room, num_agents=2, depth=True, gt_map=True, **SMALL)
    obs, _ = env.reset(seed=3)
    assert set(obs) == {"agent_0", "agent_1"}
    o = obs["agent_0"]
    assert o["panorama"].shape == (3, 16, 64) and o["panorama"].dtype == np.uint8
    assert o["goal"].shape == (3, 16, 16)
    assert o["depth"].shape == (16, 64)
    assert (o["depth"][8:] > 0).all()  # below the horizon: floor or walls everywhere
    assert (o["depth"][:4] == 0).any()  # no ceiling in this room: no hit = 0
    assert o["gt_map"].shape == (2, 64, 64)
    assert o["gt_map"][1].sum() > o["gt_map"][0].sum() > 0  # sees walls, explored more
    np.testing.assert_array_equal(o["pose"], 0.0)  # the start frame
    picture = env.render()
    assert picture.ndim == 3 and picture.shape[2] == 3 and picture.shape[1] > 64 + 16


def test_bad_actions_name_the_agent(open_room):
    env = make_parallel_env(open_room, num_agents=2, **SMALL)
    env.reset(seed=0)
    with pytest.raises(ActionError, match="agent_1"):
        env.step({"agent_0": np.zeros(2), "agent_1": np.array([np.nan, 0.0])})
    with pytest.raises(ActionError, match="no action given for live agent agent_1"):
        env.step({"agent_0": np.zeros(2)})
    with pytest.raises(ActionError, match="shape"):
        env.step({"agent_0": np.zeros(3), "agent_1": np.zeros(2)})


def test_other_agents_are_visible_but_not_oneself(open_room):
    env = VectorEnv([open_room], 1, EnvConfig(num_agents=2, panorama_width=128,
                                              panorama_height=32, goal_size=16), seed=0)
    env.reset(seed=0)
    world = env.groups[0].world
    world.position[0] = [[3.0, 4.0], [4.5, 4.0]]  # agent_1 1.5 m ahead of agent_0
    world.yaw[0] = [0.0, 0.0]
    sensors = env.groups[0].sensors
    views = sensors.panoramas(world.poses())
    bare = sensors.renderer.render(world.poses()[0], "panorama").depth  # no bodies at all
    ahead = views.depth[0, 0, 16:, 64]  # agent_0: below the horizon, straight ahead
    assert ahead.min() == pytest.approx(1.5 - 0.18, abs=0.05)  # agent_1's body front
    assert (ahead <= bare[0, 16:, 64]).all() and (ahead < bare[0, 16:, 64]).any()
    # agent_1 sees exactly what it would see with no bodies: its own is never drawn,
    # and agent_0 stands behind it, out of this column
    np.testing.assert_array_equal(views.depth[0, 1, :, 64], bare[1, :, 64])


def test_vector_env_autoresets_and_reports_records(open_room):
    cfg = EnvConfig(num_agents=2, **SMALL)
    env = VectorEnv([open_room], 3, cfg, seed=1)
    obs, _ = env.reset(seed=1)
    rng = np.random.default_rng(0)
    seen: list[AgentRecord] = []
    for _ in range(cfg.max_steps):
        obs, reward, term, trunc, info = env.step(rng.uniform(-1, 1, (3, 2, 2)))
        assert reward.shape == term.shape == trunc.shape == (3, 2)
        assert not (term & trunc).any()
        seen += info["episode_records"]
        for e in np.flatnonzero(info["episode_done"]):
            assert obs["step"][e].tolist() == [0, 0] and obs["active"][e].all()
    assert len(seen) == 6  # every env finished once by T = 12
    for r in seen:
        assert r.steps <= cfg.max_steps and r.path_length >= 0
        assert r.success == (r.final_distance <= 1.0)


def test_same_seed_same_trajectories_and_observations(door_scene):
    def rollout(seed):
        env = VectorEnv([door_scene], 2, EnvConfig(num_agents=2, odometry_noise=0.01, **SMALL),
                        seed=seed)
        obs, _ = env.reset(seed=seed)
        out = [obs["panorama"].copy(), obs["pose_delta"].copy()]
        rng = np.random.default_rng(seed)
        for _ in range(8):
            obs, r, *_ = env.step(rng.uniform(-1, 1, (2, 2, 2)))
            out += [obs["panorama"].copy(), obs["pose_delta"].copy(), r.copy()]
        return out

    a, b, c = rollout(5), rollout(5), rollout(6)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    assert any(not np.array_equal(x, y) for x, y in zip(a, c, strict=True))


def test_episodes_of_another_scene_are_refused(open_room, door_scene):
    from collavn.datasets.generator import sample_episodes

    eps = sample_episodes(door_scene, "commongoal", 2, "easy", 1, np.random.default_rng(0))
    with pytest.raises(Exception, match="made for scene door"):
        VectorEnv([open_room], 1, EnvConfig(num_agents=2, **SMALL), episodes=[eps])


def test_random_episode_on_the_real_house(shared_scene, tmp_path):
    from collavn.scenes import load_scene

    house = load_scene(str(shared_scene("aws_small_house.glb")), cache_dir=tmp_path)
    env = VectorEnv([house], 2, EnvConfig(num_agents=2, max_steps=10, **{
        k: v for k, v in SMALL.items() if k != "max_steps"}), seed=0)
    obs, _ = env.reset(seed=0)
    assert obs["panorama"].std() > 5  # a textured house, not a blank image
    rng = np.random.default_rng(0)
    records = []
    for _ in range(10):
        obs, _, *_, info = env.step(rng.uniform(-1, 1, (2, 2, 2)))
        records += info["episode_records"]
        world = env.groups[0].world
        assert house.nav.is_navigable(world.position).all()
    assert len(records) == 4 and all(r.steps <= 10 for r in records)


def test_vector_env_delivers_torch_tensors_on_request(open_room):
    import torch

    env = VectorEnv([open_room], 2, EnvConfig(num_agents=2, obs_device="cpu", **SMALL), seed=0)
    obs, _ = env.reset(seed=0)
    assert isinstance(obs["panorama"], torch.Tensor) and obs["panorama"].dtype == torch.uint8
    assert obs["panorama"].shape == (2, 2, 3, 16, 64)
    obs, *_ = env.step(torch.zeros(2, 2, 2))
    assert isinstance(obs["pose_delta"], torch.Tensor)
    assert torch.equal(obs["pose_delta"], torch.zeros(2, 2, 3))  # standing still


def test_the_free_space_sensor_reads_the_depth_it_renders(open_room):
    from collavn.envs.free_space import FREE_SPACE_RANGE, free_runs
    from collavn.errors import ConfigError
    from collavn.simulation.kinematics import AgentParams

    cfg = EnvConfig(num_agents=2, depth=True, free_space=8, **SMALL)
    env = VectorEnv([open_room], 2, cfg, seed=4)
    obs, _ = env.reset(seed=4)
    assert obs["free_space"].shape == (2, 2, 8) and obs["free_space"].dtype == np.float32
    expected = free_runs(obs["depth"], AgentParams().radius, horizon=FREE_SPACE_RANGE,
                         directions=8)
    np.testing.assert_allclose(obs["free_space"], expected, rtol=1e-6)
    assert (obs["free_space"] > 0).all() and (obs["free_space"] < FREE_SPACE_RANGE).any()
    again, _ = VectorEnv([open_room], 2, cfg, seed=4).reset(seed=4)
    np.testing.assert_array_equal(again["free_space"], obs["free_space"])
    parallel = make_parallel_env(open_room, num_agents=2, free_space=8, **SMALL)
    assert parallel.observation_space("agent_0")["free_space"].shape == (8,)
    assert parallel.reset(seed=3)[0]["agent_1"]["free_space"].shape == (8,)
    with pytest.raises(ConfigError, match=r"--env.free-space 5 must divide the panorama width"):
        EnvConfig(free_space=5, **SMALL)


def test_collision_penalty_option_sets_what_a_collision_costs(open_room):
    from dataclasses import replace

    from collavn.errors import ConfigError

    base = EnvConfig(num_agents=2, **SMALL)
    envs = [VectorEnv([open_room], 1, replace(base, collision_penalty=c), seed=5,
                      autoreset=False) for c in (0.05, 0.3)]
    for env in envs:
        env.reset(seed=5)
    assert [env.task.collision_penalty for env in envs] == [0.05, 0.3]
    worlds = [env.groups[0].world for env in envs]
    hits = 0
    for _ in range(12):  # full speed ahead, turning a little: walls come soon
        before = worlds[0].collisions.copy()
        rewards = [env.step(np.tile([1.0, 0.2], (1, 2, 1)))[1] for env in envs]
        collided = worlds[0].collisions - before
        np.testing.assert_array_equal(worlds[1].collisions, worlds[0].collisions)
        np.testing.assert_allclose(rewards[0] - rewards[1], 0.25 * collided, atol=1e-9)
        hits += int(collided.sum())
    assert hits > 0
    with pytest.raises(ConfigError, match=r"--env\.collision-penalty"):
        EnvConfig(collision_penalty=-0.1)


def test_gt_maps_mark_every_depth_hit_in_its_cell(open_room):
    from collavn.envs.sensors import Sensors

    env = VectorEnv([open_room], 2, EnvConfig(num_agents=2, depth=True, gt_map=True, **SMALL),
                    seed=4)
    obs, _ = env.reset(seed=4)
    sensors: Sensors = env.groups[0].sensors
    m, nav = env.config.gt_map_size, open_room.nav.config
    depth = obs["depth"].copy()
    depth[0, 0, :, :3] = np.inf  # rays that must be skipped like misses
    maps = sensors.gt_maps(np.zeros((2, 2, 3)), depth)
    want = np.zeros_like(maps)  # one pixel at a time, as the docstring says
    rays = sensors.panorama.ray_directions().astype(np.float64)
    for e, n in np.ndindex(2, 2):
        for p, d in enumerate(depth[e, n].reshape(-1).astype(np.float64)):
            if not (np.isfinite(d) and d > 0):
                continue
            forward, left, up = d * rays[p]
            row = int(np.floor(m / 2 - forward / nav.resolution))
            col = int(np.floor(m / 2 - left / nav.resolution))
            if 0 <= row < m and 0 <= col < m:
                want[e, n, 1, row, col] = 1.0
                height = up + sensors.panorama.mount_height
                if nav.step_height <= height <= nav.agent_height:
                    want[e, n, 0, row, col] = 1.0
    body = int(np.ceil(nav.agent_radius / nav.resolution))
    want[:, :, 1, m // 2 - body:m // 2 + body, m // 2 - body:m // 2 + body] = 1.0
    np.testing.assert_array_equal(maps, want)
    assert want[:, :, 0].sum() > 0 and want[:, :, 1].sum() > want[:, :, 0].sum()
    with pytest.raises(ValueError, match=r"depth \(2, 2, 16, 32\) does not fit 2×2 panoramas"):
        sensors.gt_maps(np.zeros((2, 2, 3)), depth[..., :32])
