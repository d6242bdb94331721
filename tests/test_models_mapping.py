import math

import numpy as np
import pytest
import torch

from collavn.models.config import MapConfig
from collavn.models.mapping import (
    MapBuilder,
    MapEncoder,
    egocentric_window,
    integrate_pose,
    location_disk,
    map_loss,
    register_patch,
)

torch.set_num_threads(1)
RES = 0.1


def reference_patch(world: np.ndarray, pose: tuple[float, float, float], m: int) -> np.ndarray:
    """Ground-truth egocentric projection: world cell under every patch cell centre."""
    s = world.shape[0]
    px, py, yaw = pose
    out = np.zeros((m, m), dtype=np.float32)
    for r in range(m):
        for c in range(m):
            xl, yl = (m / 2 - r - 0.5) * RES, (m / 2 - c - 0.5) * RES
            x = px + math.cos(yaw) * xl - math.sin(yaw) * yl
            y = py + math.sin(yaw) * xl + math.cos(yaw) * yl
            i, j = math.floor(s / 2 - x / RES), math.floor(s / 2 - y / RES)
            if 0 <= i < s and 0 <= j < s:
                out[r, c] = world[i, j]
    return out


def footprint(pose: tuple[float, float, float], s: int, m: int) -> np.ndarray:
    """World cells under the patch cell centres (reference, by loops)."""
    px, py, yaw = pose
    out = np.zeros((s, s), dtype=bool)
    for r in range(m):
        for c in range(m):
            xl, yl = (m / 2 - r - 0.5) * RES, (m / 2 - c - 0.5) * RES
            x = px + math.cos(yaw) * xl - math.sin(yaw) * yl
            y = py + math.sin(yaw) * xl + math.cos(yaw) * yl
            i, j = math.floor(s / 2 - x / RES), math.floor(s / 2 - y / RES)
            if 0 <= i < s and 0 <= j < s:
                out[i, j] = True
    return out


def blocky_world(s: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    coarse = (rng.random((s // 4, s // 4)) < 0.3).astype(np.float32)
    return np.kron(coarse, np.ones((4, 4), dtype=np.float32))


def test_integrate_pose_hand_computed():
    pose = torch.tensor([[1.0, 0.0, math.pi / 2]])
    new = integrate_pose(pose, torch.tensor([[1.0, 0.5, math.pi / 2]]))
    assert torch.allclose(new, torch.tensor([[0.5, 1.0, -math.pi]]), atol=1e-6)  # yaw wraps


def test_register_single_cell_hand_computed():
    # Agent at (1.0, 0) facing +y. Patch cell (11, 31) of a 64 patch is 2.05 m ahead,
    # 0.05 m left: world (0.95, 2.05) -> map cell (54, 43) of a 128 map.
    patch = torch.zeros(1, 1, 64, 64)
    patch[0, 0, 11, 31] = 1.0
    out = register_patch(patch, torch.tensor([[1.0, 0.0, math.pi / 2]]), 128, RES, "nearest")
    assert out[0, 0, 54, 43] == 1.0
    assert out.sum() == 1.0


@pytest.mark.parametrize("pose", [(0.0, 0.0, 0.0), (1.0, -0.6, math.pi / 2),
                                  (-0.8, 1.2, math.pi), (0.3, 0.5, -math.pi / 2)])
def test_registration_reproduces_ground_truth_exactly(pose):
    s, m = 96, 32
    world = blocky_world(s, 0)
    gt_patch = torch.from_numpy(reference_patch(world, pose, m))[None, None]
    out = register_patch(gt_patch, torch.tensor([pose]), s, RES, "nearest")[0, 0].numpy()
    seen = footprint(pose, s, m)
    assert seen.sum() == m * m
    np.testing.assert_array_equal(out[seen], world[seen])
    assert (out[~seen] == 0).all()


def test_registration_arbitrary_rotation_matches_mostly():
    s, m, pose = 96, 32, (0.42, -0.37, 0.61)
    world = blocky_world(s, 1)
    gt_patch = torch.from_numpy(reference_patch(world, pose, m))[None, None]
    out = register_patch(gt_patch, torch.tensor([pose]), s, RES, "nearest")[0, 0].numpy()
    inner = reference_patch(np.ones((s, s), np.float32), pose, m - 4)  # not the rim
    inside = register_patch(torch.from_numpy(inner)[None, None], torch.tensor([pose]), s,
                            RES, "nearest")[0, 0].numpy() > 0
    agreement = (out[inside] == world[inside]).mean()
    assert agreement > 0.93


def test_egocentric_window_inverts_registration():
    s, m, pose = 64, 32, (0.5, -0.3, math.pi / 2)
    patch = torch.rand(1, 2, m, m)
    placed = register_patch(patch, torch.tensor([pose]), s, RES, "nearest")
    back = egocentric_window(placed, torch.tensor([pose]), m, m * RES, s * RES, "nearest")
    assert torch.allclose(back, patch)


def test_map_builder_fuses_two_ground_truth_views():
    cfg = MapConfig(size=96, resolution=RES, local_size=32, feature_channels=4,
                    feature_size=6, hidden=16, encoder_size=16, embed_dim=8)
    builder = MapBuilder(cfg, (3, 16, 64))
    world = blocky_world(96, 2)
    delta = torch.tensor([[1.0, 0.0, math.pi / 2]])
    pose0 = torch.zeros(1, 3)
    pose1 = integrate_pose(pose0, delta)
    grid = torch.zeros(1, 4, 96, 96)
    feats = torch.zeros(1, 4, 6, 6)
    for pose in (pose0, pose1):
        p = tuple(pose[0].tolist())
        occ = torch.from_numpy(reference_patch(world, p, 32))
        local = torch.stack([occ, torch.ones_like(occ)])[None]
        grid, feats = builder.fuse(local, torch.ones(1, 4), pose, grid, feats, "nearest")
    seen = footprint((0, 0, 0), 96, 32) | footprint(tuple(pose1[0].tolist()), 96, 32)
    got = grid[0].numpy()
    np.testing.assert_array_equal(got[0][seen], world[seen])
    np.testing.assert_array_equal(got[1], seen.astype(np.float32))
    assert got[3][48 - 10 - 1:48 - 10 + 1, 48 - 1:48 + 1].min() == 1.0  # agent at (1, 0)
    assert got[2][47:49, 47:49].min() == 1.0  # trajectory keeps the start
    assert got[3][47:49, 47:49].max() == 0.0
    assert torch.allclose(feats[0, :, 2:4, 2:4], torch.ones(4, 2, 2))  # fully seen cells
    assert (feats[0, :, 0, 0] == 0).all() and feats.max() <= 1.0  # never seen


def test_map_builder_forward_shapes_and_episode_start():
    torch.manual_seed(0)
    cfg = MapConfig(size=64, resolution=0.2, local_size=16, feature_channels=8,
                    feature_size=4, hidden=32, encoder_size=16, embed_dim=24)
    builder, encoder = MapBuilder(cfg, (3, 16, 64)), MapEncoder(cfg)
    b = 3
    pano = torch.randint(0, 256, (b, 3, 16, 64), dtype=torch.uint8)
    step = builder(pano, None, torch.ones(b, 3), torch.zeros(b, 4, 64, 64),
                   torch.zeros(b, 8, 4, 4), torch.ones(b, 3), torch.tensor([True, False, True]))
    assert step.grid.shape == (b, 4, 64, 64) and step.features.shape == (b, 8, 4, 4)
    assert step.logits.shape == (b, 2, 16, 16)
    assert torch.equal(step.pose[0], torch.zeros(3))
    assert not torch.equal(step.pose[1], torch.zeros(3))
    assert step.grid[0, 3, 31:33, 31:33].min() == 1.0
    vec = encoder(step.grid, step.features, step.pose)
    assert vec.shape == (b, 24) and encoder.output_size == 24


def test_map_builder_depth_channel():
    cfg = MapConfig(size=32, resolution=0.2, local_size=16, feature_channels=4,
                    feature_size=4, hidden=16, encoder_size=16, embed_dim=8, use_depth=True)
    builder = MapBuilder(cfg, (3, 16, 64))
    pano = torch.randint(0, 256, (2, 3, 16, 64), dtype=torch.uint8)
    logits, _ = builder.predictor(pano, torch.rand(2, 16, 64) * 5)
    assert logits.shape == (2, 2, 16, 16)
    with pytest.raises(ValueError, match="depth"):
        builder.predictor(pano, None)


def test_location_disk_radius():
    disk = location_disk(torch.zeros(1, 3), 20, 0.1, 0.2)
    assert disk.shape == (1, 1, 20, 20)
    assert disk.sum() == 12  # cell centres within 0.2 m of a cell corner


def test_map_loss_values():
    gt = torch.zeros(2, 2, 8, 8)
    gt[:, :, :4] = 1.0
    assert torch.isclose(map_loss(torch.zeros(2, 2, 8, 8), gt), torch.tensor(math.log(2.0)))
    perfect = (gt * 2 - 1) * 50
    assert map_loss(perfect, gt) < 1e-6
    fine = gt.repeat_interleave(2, -1).repeat_interleave(2, -2)  # 10 cm gt for a 20 cm model
    assert map_loss(perfect, fine) < 1e-6


def test_map_feature_channels_learn_from_the_policy_loss():
    from collavn.models import ActorCritic, CommConfig, ModelConfig
    from collavn.training.config import PPOConfig
    from collavn.training.map_training import map_parameters, policy_parameters
    from collavn.training.ppo import ppo_loss
    from collavn.training.rollout import Rollout

    torch.manual_seed(0)
    model = ActorCritic(ModelConfig.cpu(
        panorama_shape=(3, 16, 64), goal_shape=(3, 16, 16), embed_dim=32, hidden_size=32,
        critic_hidden_size=16,
        map=MapConfig(size=32, resolution=0.2, local_size=16, feature_channels=4,
                      feature_size=4, hidden=32, encoder_size=16, embed_dim=16),
        comm=CommConfig(query_dim=16, key_dim=16, value_dim=24)))
    builder = model.towers[0].map_builder
    in_policy = {id(p) for p in policy_parameters(model)}
    in_map = {id(p) for p in map_parameters(model)}
    projection = list(builder.feature_proj.parameters())
    assert all(id(p) in in_policy and id(p) not in in_map for p in projection)
    assert all(id(p) in in_map for p in builder.predictor.parameters())

    g = torch.Generator().manual_seed(0)
    e, n, steps = 2, 2, 3

    def obs():
        return dict(
            panorama=torch.randint(0, 256, (e, n, 3, 16, 64), generator=g, dtype=torch.uint8),
            goal=torch.randint(0, 256, (e, n, 3, 16, 16), generator=g, dtype=torch.uint8),
            pose_delta=torch.randn(e, n, 3, generator=g) * 0.3,
            free_space=torch.rand(e, n, 16, generator=g) * 4.0,
            active=torch.ones(e, n, dtype=torch.bool))

    state = model.initial_state(e, n)
    first = obs()
    rollout = Rollout.allocate(steps, first, state)
    current, start = first, torch.ones(e, n, dtype=torch.bool)
    for t in range(steps):
        out = model.act(current, state, start)
        rollout.insert(t, current, start, out.raw_action, out.log_prob, out.value)
        state, current, start = out.state, obs(), torch.zeros_like(start)
    advantages, returns = torch.randn(steps, e, n, generator=g), torch.randn(steps, e, n,
                                                                             generator=g)
    optimizer = torch.optim.Adam(policy_parameters(model), lr=1e-3)
    before = [p.detach().clone() for p in builder.feature_proj.parameters()]
    predictor = [p.detach().clone() for p in builder.predictor.parameters()]
    loss, _ = ppo_loss(model, rollout, advantages, returns, PPOConfig())
    optimizer.zero_grad()
    loss.backward()
    optimizer.step()
    for old, new in zip(before, builder.feature_proj.parameters(), strict=True):
        assert not torch.equal(old, new)
    for old, new in zip(predictor, builder.predictor.parameters(), strict=True):
        assert torch.equal(old, new)  # the predictor learns from map_loss only


def test_map_encoder_widths_are_checked_and_used():
    with pytest.raises(ValueError, match="encoder_channels"):
        MapConfig(encoder_channels=(16, 32))  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="encoder_channels"):
        MapConfig(encoder_channels=(16, 0, 32))
    enc = MapEncoder(MapConfig(size=32, local_size=16, encoder_size=16, feature_channels=4,
                               feature_size=4, embed_dim=8, encoder_channels=(3, 5, 7)))
    convs = [m for m in enc.grid_net if isinstance(m, torch.nn.Conv2d)]
    assert [c.out_channels for c in convs] == [3, 5, 7]
    out = enc.encode(torch.rand(2, 4, 16, 16), torch.rand(2, 4, 4, 4))
    assert out.shape == (2, 8)
