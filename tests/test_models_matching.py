import pytest
import torch
import torch.nn.functional as F

from collavn.configs import from_dict, to_dict
from collavn.errors import ConfigError
from collavn.models import ActorCritic, GoalMatcher, MatchConfig, ModelConfig

torch.set_num_threads(1)


def matcher(seed: int = 0) -> GoalMatcher:
    torch.manual_seed(seed)
    return GoalMatcher(MatchConfig(enabled=True), (3, 32, 128), (3, 32, 32))


def panoramas(b: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (b, 3, 32, 128), generator=g, dtype=torch.uint8)


@pytest.mark.parametrize("start", [0, 40, 100])
def test_goal_cut_from_the_panorama_peaks_at_its_azimuth(start):
    pano = panoramas(4, 1)
    cols = torch.arange(start, start + 32) % 128          # wraps for start = 100
    goal = pano[..., cols].clone()
    prof = matcher().profile(pano, goal)
    assert prof.shape == (4, 3, 32)
    centre = ((start + 16) // 4) % 32
    assert (prof[:, 0].argmax(-1) == centre).all()
    assert (prof[:, 0].max(-1).values > 0.9).all()
    assert prof.abs().max() <= 1.0 + 1e-5


@pytest.mark.parametrize("shift", [1, 5, 31])
def test_rolling_the_panorama_rolls_the_profile(shift):
    m, pano = matcher(), panoramas(3, 2)
    goal = panoramas(3, 3)[..., :32]
    prof = m.profile(pano, goal)
    rolled = m.profile(torch.roll(pano, 4 * shift, dims=-1), goal)
    torch.testing.assert_close(rolled, torch.roll(prof, shift, dims=-1), atol=1e-5, rtol=0)


def test_profile_equals_brute_force_normalised_correlation():
    m, pano, goal = matcher(4), panoramas(2, 4), panoramas(2, 5)[..., 64:96]
    with torch.no_grad():
        feats, tmpl = m.features(pano, wrap=True), m.features(goal)
        prof = m.profile(pano, goal)
    for k, (h, w) in enumerate(m.template_hw):
        t = F.interpolate(tmpl, size=(h, w), mode="bilinear", align_corners=False)
        t = (t - t.mean()).flatten(1)
        top = (8 - h) // 2
        for b in range(2):
            for x in range(32):
                cols = torch.arange(x - w // 2, x - w // 2 + w) % 32
                win = feats[b, :, top:top + h][..., cols].flatten()
                win = win - win.mean()
                ref = (win @ t[b]) / (win.norm() * t[b].norm())
                assert abs(float(ref) - float(prof[b, k, x])) < 1e-3  # float32 box sums


def test_matcher_is_trainable_and_rejects_bad_sizes():
    m = matcher()
    m(panoramas(2, 6), panoramas(2, 7)[..., :32]).sum().backward()
    assert m.trunk[0].weight.grad is not None and m.trunk[0].weight.grad.abs().sum() > 0
    with pytest.raises(ValueError, match="multiples of 4"):
        GoalMatcher(MatchConfig(enabled=True), (3, 30, 128), (3, 32, 32))
    with pytest.raises(ValueError, match="channels"):
        MatchConfig(enabled=True, channels=3)


def test_policy_with_and_without_matching_and_old_configs():
    cfg = ModelConfig.cpu()
    assert cfg.goal_match.enabled and ModelConfig.paper().goal_match.enabled is False
    on, off = ActorCritic(cfg), ActorCritic(ModelConfig.cpu(goal_match=MatchConfig()))
    assert on.towers[0].goal_matcher is not None and off.towers[0].goal_matcher is None
    obs = dict(panorama=panoramas(2, 8).view(1, 2, 3, 32, 128),
               goal=panoramas(2, 9)[..., :32].reshape(1, 2, 3, 32, 32),
               pose_delta=torch.zeros(1, 2, 3), free_space=torch.ones(1, 2, 16),
               active=torch.ones(1, 2, dtype=torch.bool))
    start = torch.ones(1, 2, dtype=torch.bool)
    for model in (on, off):
        out = model.act(obs, model.initial_state(1, 2), start)
        assert out.action.shape == (1, 2, 2) and torch.isfinite(out.value).all()
    # configs round-trip exactly; one saved without goal matching is refused by name
    d = to_dict(off.cfg)
    d.pop("goal_match")
    with pytest.raises(ConfigError, match="missing key goal_match"):
        from_dict(ModelConfig, d)
    assert from_dict(ModelConfig, to_dict(cfg)) == cfg
