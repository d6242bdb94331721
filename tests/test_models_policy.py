import pytest
import torch

from collavn.models import ActorCritic, AgentState, CommConfig, MapConfig, ModelConfig, map_loss
from collavn.models.mapping import blend_features
from collavn.models.policy import action_mean, gru_step

torch.set_num_threads(1)


def tiny(variant: str = "memory", **overrides) -> ModelConfig:
    return ModelConfig.cpu(
        panorama_shape=(3, 16, 64), goal_shape=(3, 16, 16), embed_dim=32, hidden_size=32,
        critic_hidden_size=16,
        map=MapConfig(size=32, resolution=0.2, local_size=16, feature_channels=4,
                      feature_size=4, hidden=32, encoder_size=16, embed_dim=16),
        comm=CommConfig(variant=variant, query_dim=16, key_dim=16, value_dim=24), **overrides)


def observations(e: int, n: int, seed: int, shape=(16, 64), goal=(16, 16)):
    g = torch.Generator().manual_seed(seed)
    return dict(
        panorama=torch.randint(0, 256, (e, n, 3, *shape), generator=g, dtype=torch.uint8),
        goal=torch.randint(0, 256, (e, n, 3, *goal), generator=g, dtype=torch.uint8),
        pose_delta=torch.randn(e, n, 3, generator=g) * 0.3,
        free_space=torch.rand(e, n, 16, generator=g) * 4.0,  # read iff free_space_input
        explore_action=torch.rand(e, n, 2, generator=g) * 2 - 1,  # read iff explore_prior
        active=torch.ones(e, n, dtype=torch.bool))


@pytest.mark.parametrize("variant", ["none", "handshake", "memory"])
@pytest.mark.parametrize("n", [1, 2, 3, 4])
def test_shapes_for_any_number_of_agents(variant, n):
    torch.manual_seed(0)
    cfg = tiny(variant)
    model = ActorCritic(cfg)
    e = 2
    state = model.initial_state(e, n)
    out = model.act(observations(e, n, 0), state, torch.ones(e, n, dtype=torch.bool))
    assert out.action.shape == (e, n, 2) and out.raw_action.shape == (e, n, 2)
    assert out.action.abs().max() <= 1.0
    assert out.log_prob.shape == (e, n) and out.value.shape == (e, n)
    assert out.bytes_sent.shape == (e, n) and out.message.scores.shape == (e, n, n)
    omega_dim = 0 if variant == "none" else cfg.comm.value_dim
    assert out.message.omega.shape == (e, n, omega_dim)
    s = out.state
    assert s.grid.shape == (e, n, 4, 32, 32) and s.features.shape == (e, n, 4, 4, 4)
    assert s.actor_h.shape == (e, n, 32) and s.critic_h.shape == (e, n, 16)
    slots = 80 if variant == "memory" else 0
    assert s.mem_keys.shape == (e, n, slots, 16) and s.mem_values.shape == (e, n, slots, 24)


def test_finished_agents_keep_their_state_and_are_not_matched():
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    n = 3
    state = model.initial_state(1, n)
    start = torch.ones(1, n, dtype=torch.bool)
    state = model(observations(1, n, 0), state, start).state
    obs = observations(1, n, 1)
    obs["active"] = torch.tensor([[True, False, True]])
    out = model(obs, state, torch.zeros(1, n, dtype=torch.bool))
    for name in ("actor_h", "critic_h", "grid", "pose", "mem_keys", "mem_count", "steps"):
        assert torch.equal(getattr(out.state, name)[0, 1], getattr(state, name)[0, 1]), name
    assert out.state.mem_count.tolist() == [[2, 1, 2]]
    assert (out.message.scores[0, :, 1] == 0).all() and out.message.bytes_sent[0, 1] == 0
    assert torch.equal(out.message.omega[0, 1], torch.zeros(24))


def test_ad_hoc_team_size_same_weights():
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    for n in (2, 3):
        out = model.act(observations(1, n, 0), model.initial_state(1, n),
                        torch.ones(1, n, dtype=torch.bool), deterministic=True)
        assert out.action.shape == (1, n, 2)


def test_per_agent_parameters():
    torch.manual_seed(0)
    shared = ActorCritic(tiny())
    per_agent = ActorCritic(tiny(per_agent_params=True, max_agents=3))
    count = sum(p.numel() for p in per_agent.parameters())
    assert count == 3 * sum(p.numel() for p in shared.parameters())
    out = per_agent(observations(2, 3, 0), per_agent.initial_state(2, 3),
                    torch.ones(2, 3, dtype=torch.bool))
    assert out.value.shape == (2, 3)
    with pytest.raises(ValueError, match="max_agents"):
        per_agent(observations(1, 4, 0), per_agent.initial_state(1, 4),
                  torch.ones(1, 4, dtype=torch.bool))


def test_deterministic_action_is_clipped_mean():
    torch.manual_seed(0)
    model = ActorCritic(tiny(log_std_init=0.0))
    with torch.no_grad():
        model.towers[0].actor_mean.bias.fill_(3.0)
    out = model.act(observations(1, 2, 0), model.initial_state(1, 2),
                    torch.ones(1, 2, dtype=torch.bool), deterministic=True)
    assert torch.allclose(out.action, torch.ones(1, 2, 2))
    assert (out.raw_action > 2.9).all()


@pytest.mark.parametrize("prior", [False, True])
def test_evaluate_actions_reproduces_rollout_log_probs(prior):
    torch.manual_seed(0)
    model = ActorCritic(tiny(explore_prior=prior)).eval()
    e, n, steps = 2, 3, 4
    state0 = model.initial_state(e, n)
    state = state0
    starts = torch.zeros(steps, e, n, dtype=torch.bool)
    starts[0] = True
    starts[2, 1] = True  # env 1 starts a new episode mid-sequence
    seq, acts, logps, values = [], [], [], []
    for t in range(steps):
        obs = observations(e, n, t)
        out = model.act(obs, state, starts[t])
        seq.append(obs)
        acts.append(out.raw_action)
        logps.append(out.log_prob)
        values.append(out.value)
        state = out.state
    stacked = {k: torch.stack([o[k] for o in seq]) for k in seq[0]}
    ev = model.evaluate_actions(stacked, state0, starts, torch.stack(acts))
    assert torch.allclose(ev.log_prob, torch.stack(logps), atol=1e-5)
    assert torch.allclose(ev.value, torch.stack(values), atol=1e-5)
    assert ev.entropy.shape == (steps, e, n)
    loss = -ev.log_prob.mean() + ev.value.pow(2).mean()
    loss.backward()
    grads = [p.grad for p in model.parameters() if p.grad is not None]
    assert grads and any(g.abs().sum() > 0 for g in grads)


def test_map_logits_train_with_map_loss():
    torch.manual_seed(0)
    model = ActorCritic(tiny("none"))
    out = model(observations(1, 2, 0), model.initial_state(1, 2),
                torch.ones(1, 2, dtype=torch.bool))
    gt = torch.rand(1, 2, 2, 32, 32)  # 10 cm gt over the same 3.2 m as the 20 cm patch
    loss = map_loss(out.map_logits, gt)
    loss.backward()
    predictor = model.towers[0].map_builder.predictor
    assert predictor.decoder[-1].weight.grad.abs().sum() > 0


def test_state_reset_and_device():
    torch.manual_seed(0)
    model = ActorCritic(tiny(), device="cpu")
    state = model.initial_state(2, 2)
    assert state.grid.device == model.device
    out = model(observations(2, 2, 0), state, torch.ones(2, 2, dtype=torch.bool))
    reset = out.state.reset(torch.tensor([[True, False], [False, False]]))
    assert reset.grid[0, 0].abs().sum() == 0 and reset.grid[0, 1].abs().sum() > 0
    assert isinstance(reset.detach(), AgentState)
    assert reset.select_envs(slice(0, 1)).num_envs == 1


def test_paper_size_shapes():
    torch.manual_seed(0)
    cfg = ModelConfig.paper()
    model = ActorCritic(cfg).eval()
    with torch.no_grad():
        out = model(observations(1, 2, 0, shape=(128, 512), goal=(128, 128)),
                    model.initial_state(1, 2), torch.ones(1, 2, dtype=torch.bool))
    assert out.state.grid.shape == (1, 2, 4, 384, 384)
    assert out.state.features.shape == (1, 2, 256, 13, 13)
    assert out.map_logits.shape == (1, 2, 2, 64, 64)
    assert out.message.omega.shape == (1, 2, 2048) and out.value.shape == (1, 2)


def test_odometry_input_reaches_the_actor_but_not_at_an_episode_start():
    torch.manual_seed(0)
    model = ActorCritic(tiny("none", odometry_input=True, free_space_input=0))
    plain = ActorCritic(tiny("none", odometry_input=False, free_space_input=0))
    assert model.towers[0].actor_core.input_size == plain.towers[0].actor_core.input_size + 3
    obs = observations(1, 2, 3)
    delta = torch.tensor([[0.7, 0.0, 0.2], [0.0, 0.0, 0.0]])
    state = model.initial_state(1, 2)
    tower = model.towers[0]
    for first in (False, True):
        logits, hidden = tower.predict_map(obs["panorama"][0], None)
        starts = torch.full((2,), first)
        _, seen, pose, window = tower.track_map(logits, delta, state.grid[0], state.pose[0],
                                                starts)
        features = blend_features(state.features[0], seen, tower.map_visual(hidden)[0])
        s = tower.embed_map(window, features, pose, delta, starts)[0]
        torch.testing.assert_close(s[:, -3:], torch.zeros_like(delta) if first else delta)
    start = torch.zeros(1, 2, dtype=torch.bool)
    out = model(dict(obs, pose_delta=delta[None]), state, start)
    assert torch.isfinite(out.dist.mean).all()


@pytest.mark.parametrize("modes", [1, 3])
def test_explore_prior_is_the_mean_of_an_untrained_head_and_an_input(modes):
    torch.manual_seed(0)
    model = ActorCritic(tiny("none", explore_prior=True, action_modes=modes))
    plain = ActorCritic(tiny("none", explore_prior=False, action_modes=modes))
    assert model.towers[0].actor_core.input_size == plain.towers[0].actor_core.input_size + 2
    with torch.no_grad():  # a head that adds nothing
        model.towers[0].actor_mean.weight.zero_()
        model.towers[0].actor_mean.bias.zero_()
    obs = observations(2, 3, 0)
    start = torch.ones(2, 3, dtype=torch.bool)
    out = model.act(obs, model.initial_state(2, 3), start, deterministic=True)
    torch.testing.assert_close(out.raw_action, obs["explore_action"])
    # the prior is also an input: a different move changes more than the added part
    moved = dict(obs, explore_action=-obs["explore_action"])
    with torch.no_grad():
        model.towers[0].actor_mean.weight.normal_()
    a = model(obs, model.initial_state(2, 3), start).dist
    b = model(moved, model.initial_state(2, 3), start).dist
    shift = action_mean(a) - action_mean(b) - 2 * obs["explore_action"]
    assert shift.abs().max() > 1e-4  # not only the additive part changed
    with pytest.raises(ValueError, match=r"EnvConfig\.explore_action"):
        model.act({k: v for k, v in obs.items() if k != "explore_action"},
                  model.initial_state(2, 3), start)


def test_gru_step_is_pytorchs_gru_cell():
    """The replay splits a GRU cell into W_ih·x (all steps at once) and the recurrence."""
    torch.manual_seed(0)
    cell = torch.nn.GRUCell(7, 5)
    x, h = torch.randn(9, 7), torch.randn(9, 5)
    gates_in = torch.nn.functional.linear(x, cell.weight_ih, cell.bias_ih)
    torch.testing.assert_close(gru_step(cell, gates_in, h), cell(x, h), rtol=1e-6, atol=1e-6)


def _fit_heads(modes: int, steps: int = 300) -> torch.Tensor:
    """Fit the actor head of one state to an expert that turns hard left or hard right,
    half the time each, by likelihood; returns the deterministic action."""
    from collavn.models.policy import action_distribution, action_mean

    torch.manual_seed(0)
    tower = ActorCritic(tiny("none", action_modes=modes)).towers[0]
    h = torch.randn(1, 32).expand(64, 32)  # one state: nothing tells the sides apart
    turn = torch.where(torch.arange(64) % 2 == 0, 0.8, -0.8)
    expert = torch.stack([torch.full((64,), 0.1), turn], dim=1)
    params = [tower.actor_mean.weight, tower.actor_mean.bias, tower.log_std,
              *([] if tower.actor_modes is None else tower.actor_modes.parameters())]
    opt = torch.optim.Adam(params, lr=0.03)
    for _ in range(steps):
        mean, log_std, logits, _ = tower.heads(h, torch.zeros(64, 16))
        loss = -action_distribution(mean, log_std, logits).log_prob(expert).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        return action_mean(action_distribution(*tower.heads(h, torch.zeros(64, 16))[:3]))


def test_one_gaussian_averages_a_left_right_choice_into_straight_on_a_mixture_picks_one():
    one, two = _fit_heads(1), _fit_heads(2)
    assert one[:, 1].abs().max() < 0.1  # the mean of ±0.8: into whatever is ahead
    assert torch.allclose(two[:, 1].abs(), torch.full((64,), 0.8), atol=0.05)
    assert (two[:, 1] == two[0, 1]).all()  # the same choice for the same state


def test_mixture_log_prob_mean_and_entropy_by_hand():
    from torch.distributions import Independent, Normal

    from collavn.models.policy import (
        action_components,
        action_distribution,
        action_mean,
        pick_component,
    )

    g = torch.Generator().manual_seed(1)
    mean, logits = torch.randn(5, 3, 2, generator=g), torch.randn(5, 3, generator=g)
    log_std = torch.randn(5, 3, 2, generator=g) * 0.3
    dist = action_distribution(mean, log_std, logits)
    x = torch.randn(5, 2, generator=g)
    comp = Normal(mean, log_std.exp()).log_prob(x[:, None]).sum(-1)  # (5, 3)
    want = torch.logsumexp(comp + torch.log_softmax(logits, -1), -1)
    torch.testing.assert_close(dist.log_prob(x), want)
    top = logits.argmax(-1)
    assert torch.equal(action_mean(dist), mean[torch.arange(5), top])
    loc, scale, parts_logits = action_components(dist)
    assert torch.equal(pick_component(loc, scale, parts_logits)[1],
                       log_std.exp()[torch.arange(5), top])
    # a uniform draw picks each component with its weight's probability (--stochastic)
    u = (torch.arange(6000) + 0.5) / 6000
    picked, _ = pick_component(loc.expand(6000, 5, 3, 2), scale.expand(6000, 5, 3, 2),
                               parts_logits.expand(6000, 5, 3), u[:, None].expand(6000, 5))
    share = (picked[..., None, :] == mean).all(-1).float().mean(0)  # (5, 3)
    torch.testing.assert_close(share, torch.softmax(logits, -1), rtol=0, atol=1e-3)
    samples = dist.sample((4000,))
    entropy = -dist.log_prob(samples).mean(0)  # Monte Carlo
    assert (dist.entropy() >= entropy - 0.05).all()
    one = action_distribution(mean[:, :1], log_std[:, :1], logits[:, :1])
    assert isinstance(one, Independent)  # one component: the plain Gaussian
    assert torch.equal(one.mean, mean[:, 0]) and torch.equal(action_mean(one), mean[:, 0])
    one_parts = action_components(one)
    one_mean, one_std = pick_component(*one_parts, u=torch.rand(5))
    assert torch.equal(one_mean, mean[:, 0]) and torch.equal(one_std, log_std[:, 0].exp())
    with pytest.raises(ValueError, match="action_modes"):
        tiny(action_modes=0)
