import math

import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from collavn.models import ActorCritic, CommConfig, MapConfig, ModelConfig
from collavn.models.communication import match_and_select, memory_mask, write_memory

torch.set_num_threads(1)
DQ, DV = 4, 3
CFG = CommConfig(query_dim=DQ, key_dim=2, value_dim=DV, temperature=0.05)


def tiny(variant: str = "memory", **comm) -> ModelConfig:
    return ModelConfig.cpu(
        panorama_shape=(3, 16, 64), goal_shape=(3, 16, 16), embed_dim=32, hidden_size=32,
        critic_hidden_size=16,
        map=MapConfig(size=32, resolution=0.2, local_size=16, feature_channels=4,
                      feature_size=4, hidden=32, encoder_size=16, embed_dim=16),
        comm=CommConfig(variant=variant, query_dim=16, key_dim=16, value_dim=24, **comm))


def observations(e: int, n: int, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return dict(
        panorama=torch.randint(0, 256, (e, n, 3, 16, 64), generator=g, dtype=torch.uint8),
        goal=torch.randint(0, 256, (e, n, 3, 16, 16), generator=g, dtype=torch.uint8),
        pose_delta=torch.randn(e, n, 3, generator=g) * 0.3,
        active=torch.ones(e, n, dtype=torch.bool))


def hand_set_round(hard: bool = True, active=None):
    """Agents 0 and 1 hold the same key; agent 2's key is orthogonal to every query."""
    keys = torch.tensor([[1.0, 0.0], [1.0, 0.0], [0.0, 1.0]]).mul(20).view(1, 3, 1, 2)
    values = torch.arange(9.0).view(1, 3, 1, DV)
    query = torch.tensor([[1.0, 0.0]]).expand(3, 2).reshape(1, 3, 2)
    mask = torch.ones(1, 3, 1, dtype=torch.bool)
    active = torch.ones(1, 3, dtype=torch.bool) if active is None else active
    return match_and_select(query, keys, values, mask, active, CFG, hard), values


def test_low_scores_send_nothing_and_self_gate_stops_message():
    msg, values = hand_set_round()
    s = msg.scores[0]
    z = torch.tensor([20.0, 20.0, 0.0]) / math.sqrt(2)
    expected = torch.softmax(z, 0)
    assert torch.allclose(s, expected.expand(3, 3), atol=1e-6)
    assert (s[:, 2] < 1 / 3).all()
    assert (msg.gates[:, :, 2] == 0).all()  # supporter below 1/N: nothing
    assert torch.equal(msg.omega[0, 2], torch.zeros(DV))  # self score <= eta: no message
    want = expected[0] * values[0, 0, 0] + expected[1] * values[0, 1, 0]
    assert torch.allclose(msg.omega[0, 0], want) and torch.allclose(msg.omega[0, 1], want)
    assert msg.links[0].tolist() == [[False, True, False], [True, False, False],
                                     [False, False, False]]
    assert msg.bytes_sent[0].tolist() == [4.0 * (DQ + 2 + DV)] * 2 + [4.0 * (DQ + 2)]


def test_soft_gate_lets_gradients_through():
    keys = torch.randn(1, 3, 2, 2, requires_grad=True)
    query = torch.randn(1, 3, 2, requires_grad=True)
    values = torch.rand(1, 3, 2, DV)
    msg = match_and_select(query, keys, values, torch.ones(1, 3, 2, dtype=torch.bool),
                           torch.ones(1, 3, dtype=torch.bool), CFG, hard=False)
    msg.omega.sum().backward()
    assert query.grad is not None and query.grad.abs().sum() > 0
    assert keys.grad is not None and keys.grad.abs().sum() > 0


def test_finished_agent_is_masked_out_of_matching():
    active = torch.tensor([[True, False, True]])
    msg, _ = hand_set_round(active=active)
    assert (msg.scores[0, :, 1] == 0).all()
    assert torch.allclose(msg.scores[0, 0, [0, 2]].sum(), torch.tensor(1.0))
    assert torch.equal(msg.omega[0, 1], torch.zeros(DV))
    assert msg.bytes_sent[0, 1] == 0 and not msg.links[0, :, 1].any()
    # With agent 1 gone, eta = 1/2: agent 0 matches itself only (score ~1).
    assert msg.scores[0, 0, 0] > 0.99 and msg.omega[0, 0].abs().sum() > 0


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 4), st.integers(1, 3), st.integers(0, 10_000))
def test_scores_are_a_distribution_over_active_agents(n, slots, seed):
    g = torch.Generator().manual_seed(seed)
    active = torch.rand(2, n, generator=g) < 0.7
    mask = torch.rand(2, n, slots, generator=g) < 0.7
    mask[..., 0] = True
    msg = match_and_select(torch.randn(2, n, 2, generator=g), torch.randn(2, n, slots, 2,
                           generator=g), torch.rand(2, n, slots, DV, generator=g), mask,
                           active, CFG, hard=True)
    total = msg.scores.sum(-1)
    for e in range(2):
        assert torch.allclose(total[e], active[e].float(), atol=1e-5)
        assert (msg.scores[e][:, ~active[e]] == 0).all()
        assert (msg.omega[e][~active[e]] == 0).all()
        assert torch.isfinite(msg.omega).all()


def test_masked_memory_entries_are_ignored():
    keys = torch.randn(1, 2, 2, 2)
    values = torch.rand(1, 2, 2, DV)
    query = torch.randn(1, 2, 2)
    mask = torch.tensor([[[True, False], [True, True]]])
    full = match_and_select(query, keys, values, mask, torch.ones(1, 2, dtype=torch.bool),
                            CFG, hard=False)
    garbage = keys.clone()
    garbage[0, 0, 1] = 1e3
    other = match_and_select(query, garbage, values, mask, torch.ones(1, 2, dtype=torch.bool),
                             CFG, hard=False)
    assert torch.allclose(full.omega, other.omega)


def test_ring_buffer_fifo():
    keys, values = torch.zeros(1, 1, 3, 1), torch.zeros(1, 1, 3, 1)
    count = torch.zeros(1, 1, dtype=torch.long)
    for step in range(1, 6):
        new = torch.full((1, 1, 1), float(step))
        keys, values, count, _ = write_memory(keys, values, count, new, new,
                                              torch.ones(1, 1, dtype=torch.bool))
    assert sorted(keys.flatten().tolist()) == [3.0, 4.0, 5.0]
    assert count.item() == 5 and memory_mask(count, 3).all()


def run(model, cfg_n: int, steps: int, seed: int = 0, e: int = 1):
    state = model.initial_state(e, cfg_n)
    start = torch.ones(e, cfg_n, dtype=torch.bool)
    outs = []
    for t in range(steps):
        out = model(observations(e, cfg_n, seed + t), state, start)
        outs.append(out)
        state, start = out.state, torch.zeros_like(start)
    return outs


def test_memory_grows_by_one_per_step_and_resets():
    torch.manual_seed(0)
    model = ActorCritic(tiny())
    outs = run(model, 3, 4)
    for t, out in enumerate(outs, start=1):
        assert (out.state.mem_count == t).all()
        assert memory_mask(out.state.mem_count, 80).sum(-1).eq(t).all()
    state = outs[-1].state.reset(torch.tensor([[True, False, True]]))
    assert state.mem_count.tolist() == [[0, 4, 0]]
    assert state.mem_values[0, 0].abs().sum() == 0 and state.mem_values[0, 1].abs().sum() > 0


def test_store_interval_and_capacity():
    torch.manual_seed(0)
    model = ActorCritic(tiny(store_interval=2, memory_slots=2))
    outs = run(model, 2, 5)
    assert [int(o.state.mem_count[0, 0]) for o in outs] == [1, 1, 2, 2, 3]
    assert outs[-1].state.mem_keys.shape[2] == 2


def test_one_step_memory_equals_handshake():
    torch.manual_seed(0)
    mem = ActorCritic(tiny("memory", memory_slots=1)).eval()
    hand = ActorCritic(tiny("handshake")).eval()
    hand.load_state_dict(mem.state_dict())
    for a, b in zip(run(mem, 3, 4), run(hand, 3, 4), strict=True):
        assert torch.equal(a.message.omega, b.message.omega)
        assert torch.equal(a.dist.mean, b.dist.mean) and torch.equal(a.value, b.value)
    assert a.message.omega.abs().sum() > 0 or a.message.scores.sum() > 0


def test_permuting_agents_permutes_messages():
    torch.manual_seed(0)
    model = ActorCritic(tiny()).train()
    perm = torch.tensor([2, 0, 3, 1])
    state = model.initial_state(1, 4)
    pstate = model.initial_state(1, 4)
    start = torch.ones(1, 4, dtype=torch.bool)
    for t in range(3):
        obs = observations(1, 4, t)
        out = model(obs, state, start)
        pout = model({k: v[:, perm] for k, v in obs.items()}, pstate, start)
        assert torch.allclose(out.message.omega[:, perm], pout.message.omega, atol=1e-5)
        assert torch.allclose(out.message.scores[:, perm][:, :, perm], pout.message.scores,
                              atol=1e-5)
        assert torch.allclose(out.value[:, perm], pout.value, atol=1e-5)
        state, pstate, start = out.state, pout.state, torch.zeros_like(start)
    assert out.message.omega.abs().sum() > 0


def test_none_variant_sends_nothing():
    model = ActorCritic(tiny("none"))
    out = run(model, 2, 2)[-1]
    assert out.message.omega.shape == (1, 2, 0)
    assert (out.message.bytes_sent == 0).all() and out.state.mem_keys.shape[2] == 0
