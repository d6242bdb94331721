import math

import pytest
import torch
import torch.nn.functional as F
from hypothesis import given, settings
from hypothesis import strategies as st
from torch import Tensor

from collavn.models import ActorCritic, CommConfig, MapConfig, ModelConfig
from collavn.models.communication import (
    communication_counts,
    match_and_select,
    memory_mask,
)
from collavn.models.policy import action_mean

torch.set_num_threads(1)
DQ, DV = 4, 3
CFG = CommConfig(query_dim=DQ, key_dim=2, value_dim=DV, temperature=0.05)
P = torch.sigmoid(torch.tensor(2.0))  # ψ of a matching key in matched_round


def tiny(variant: str = "memory", **comm) -> ModelConfig:
    return ModelConfig.cpu(
        panorama_shape=(3, 16, 64), goal_shape=(3, 16, 16), embed_dim=32, hidden_size=32,
        critic_hidden_size=16,
        map=MapConfig(size=32, resolution=0.2, local_size=16, feature_channels=4,
                      feature_size=4, hidden=32, encoder_size=16, embed_dim=16),
        comm=CommConfig(variant=variant, query_dim=16, key_dim=16, value_dim=24, **comm))


def observations(e: int, n: int, seed: int, shape=(16, 64), goal=(16, 16)):
    g = torch.Generator().manual_seed(seed)
    return dict(
        panorama=torch.randint(0, 256, (e, n, 3, *shape), generator=g, dtype=torch.uint8),
        goal=torch.randint(0, 256, (e, n, 3, *goal), generator=g, dtype=torch.uint8),
        pose_delta=torch.randn(e, n, 3, generator=g) * 0.3,
        free_space=torch.rand(e, n, 16, generator=g) * 4.0,  # read iff free_space_input
        active=torch.ones(e, n, dtype=torch.bool))


def write_memory(keys: Tensor, values: Tensor, count: Tensor, new_key: Tensor,
                 new_value: Tensor, write: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Append one entry per agent to a ring buffer (overwriting the oldest when full).

    The step-by-step definition of the memory, the reference the model's
    :func:`~collavn.models.communication.plan_memory` is tested against.

    Args:
        keys: ``(E, N, T, dk)`` stored keys.
        values: ``(E, N, T, dv)`` stored values.
        count: ``(E, N)`` int64 writes since the episode start.
        new_key: ``(E, N, dk)``.
        new_value: ``(E, N, dv)``.
        write: ``(E, N)`` bool, which agents store this step.

    Returns:
        New keys, values, count and the ``(E, N, T)`` bool one-hot of the written slot.
    """
    slots = keys.shape[2]
    if slots == 0:
        return keys, values, count, torch.zeros_like(keys[..., 0], dtype=torch.bool)
    idx = torch.arange(slots, device=count.device)
    slot = (idx == (count % slots).unsqueeze(-1)) & write.unsqueeze(-1)
    keys = torch.where(slot.unsqueeze(-1), new_key.unsqueeze(2), keys)
    values = torch.where(slot.unsqueeze(-1), new_value.unsqueeze(2), values)
    return keys, values, count + write.long(), slot


def along_query(z: torch.Tensor) -> torch.Tensor:
    """Keys ``(..., 2)`` whose score against the query (1, 0) is z (d = 2)."""
    return torch.stack([z * math.sqrt(2), torch.zeros_like(z)], dim=-1)


def matched_round(n: int, active=None):
    """Agents 0 and 1 hold a key along every query (z = +2); the others against it (z = -2)."""
    sign = torch.tensor([1.0, 1.0] + [-1.0] * (n - 2))
    keys = along_query(2 * sign).view(1, n, 1, 2)
    values = torch.arange(1.0, n * DV + 1).view(1, n, 1, DV)
    query = torch.tensor([1.0, 0.0]).expand(1, n, 2)
    active = torch.ones(1, n, dtype=torch.bool) if active is None else active
    msg = match_and_select(query, torch.zeros(1, n), keys, values,
                           torch.ones(1, n, 1, dtype=torch.bool), active, CFG)
    return msg, values[0, :, 0]


@pytest.mark.parametrize("n", [2, 3, 4])
def test_teammate_with_matching_key_enters_omega(n):
    msg, values = matched_round(n)
    want = P * (P * values[0]) + P * (P * values[1])
    assert torch.allclose(msg.omega[0, 0], want) and torch.allclose(msg.omega[0, 1], want)
    assert (msg.omega[0, 2:] == 0).all()  # own score σ(-2) ≤ 1/N: silent
    assert torch.allclose(msg.scores[0, 0], torch.tensor([P, P] + [1 - P] * (n - 2)))
    links = torch.zeros(n, n, dtype=torch.bool)
    links[0, 1] = links[1, 0] = True
    assert torch.equal(msg.links[0], links)
    counts = communication_counts(msg, torch.ones(1, n, dtype=torch.bool))
    assert counts.received[0].tolist() == [True, True] + [False] * (n - 2)
    assert counts.when[0].tolist() == [True, True] + [False] * (n - 2)
    # 0 and 1: query, one score back, value; the others: a score to each of 0 and 1.
    assert counts.bytes[0].tolist() == [4.0 * (DQ + 1 + DV)] * 2 + [4.0 * 2] * (n - 2)


def test_self_score_at_threshold_is_silent():
    keys = along_query(torch.zeros(2)).view(1, 2, 1, 2)  # ψ = σ(0) = ½ = η at N = 2
    msg = match_and_select(torch.tensor([[[1.0, 0.0]] * 2]), torch.zeros(1, 2), keys,
                           torch.ones(1, 2, 1, DV), torch.ones(1, 2, 1, dtype=torch.bool),
                           torch.ones(1, 2, dtype=torch.bool), CFG)
    assert (msg.scores == 0.5).all() and (msg.omega == 0).all()
    counts = communication_counts(msg, torch.ones(1, 2, dtype=torch.bool))
    assert not counts.received.any() and not counts.when.any()
    assert (counts.bytes == 0).all()


def test_memory_entry_is_matched_k_steps_later_by_a_lone_agent():
    z = torch.tensor([3.0, -1.0, 0.5, 2.0])  # scores of the entries stored at steps 0..3
    vals = torch.tensor([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 3.0], [4.0, 4.0, 4.0]])
    active = torch.tensor([[True, False]])  # the teammate has finished
    for slots, kept in ((4, slice(0, 4)), (3, slice(1, 4))):  # a FIFO of 3 drops step 0
        keys, values = torch.zeros(1, 2, slots, 2), torch.zeros(1, 2, slots, DV)
        count = torch.zeros(1, 2, dtype=torch.long)
        for t in range(4):
            new_k = torch.stack([along_query(z[t]), along_query(torch.tensor(9.0))])[None]
            new_v = torch.stack([vals[t], torch.full((DV,), 100.0)])[None]
            keys, values, count, _ = write_memory(keys, values, count, new_k, new_v, active)
        msg = match_and_select(torch.tensor([[[1.0, 0.0]] * 2]), torch.zeros(1, 2), keys,
                               values, memory_mask(count, slots), active, CFG)
        psi = torch.sigmoid(z[kept])
        s = psi.mean()
        v_hat = (psi[:, None] * vals[kept]).mean(0)
        assert s > 0.5  # a lone agent's η is ½, not 1
        assert torch.allclose(msg.scores[0, 0], torch.tensor([s, 0.0]))
        assert torch.allclose(msg.omega[0, 0], s * v_hat)
        assert (msg.omega[0, 1] == 0).all() and not msg.links.any()


def reference_omega(query, bias, keys, values, mask, active):
    """Slow loops over the equations of the module docstring."""
    e_n, n_n = active.shape
    omega = torch.zeros(e_n, n_n, values.shape[-1])
    for e in range(e_n):
        eta = 1.0 / max(int(active[e].sum()), 2)
        for n in range(n_n):
            if not active[e, n]:
                continue
            s, v_hat = {}, {}
            for m in range(n_n):
                entries = [t for t in range(keys.shape[2]) if mask[e, m, t]]
                if not active[e, m] or not entries:
                    continue
                psi = [torch.sigmoid(query[e, n] @ keys[e, m, t] / math.sqrt(keys.shape[-1])
                                     + bias[e, n]) for t in entries]
                s[m] = sum(psi) / len(entries)
                v_hat[m] = sum(p * values[e, m, t] for p, t in zip(psi, entries,
                                                                   strict=True)) / len(entries)
            if s.get(n, 0.0) <= eta:
                continue
            omega[e, n] = s[n] * v_hat[n] + sum(
                (s[m] * v_hat[m] for m in s if m != n and s[m] > eta), torch.zeros(DV))
    return omega


@settings(max_examples=30, deadline=None)
@given(st.integers(1, 4), st.integers(1, 3), st.integers(0, 10_000))
def test_pairs_are_scored_independently_and_match_the_reference(n, slots, seed):
    g = torch.Generator().manual_seed(seed)
    active = torch.rand(2, n, generator=g) < 0.7
    mask = torch.rand(2, n, slots, generator=g) < 0.7
    mask[..., 0] = True
    query, bias = torch.randn(2, n, 2, generator=g) * 2, torch.randn(2, n, generator=g)
    keys, values = torch.randn(2, n, slots, 2, generator=g), torch.rand(2, n, slots, DV,
                                                                        generator=g)
    msg = match_and_select(query, bias, keys, values, mask, active, CFG)
    assert torch.allclose(msg.omega, reference_omega(query, bias, keys, values, mask, active),
                          atol=1e-5)
    assert ((msg.scores >= 0) & (msg.scores <= 1)).all()
    pair = active[:, :, None] & active[:, None, :]
    assert (msg.scores[~pair] == 0).all() and (msg.omega[~active] == 0).all()
    if n >= 3:  # a third agent leaving changes no other pair's score
        fewer = active.clone()
        fewer[:, 2] = False
        other = match_and_select(query, bias, keys, values, mask, fewer, CFG)
        keep = fewer[:, :, None] & fewer[:, None, :]
        assert torch.allclose(msg.scores[keep], other.scores[keep])


def test_closed_gate_passes_a_straight_through_gradient():
    keys = along_query(torch.tensor([-0.1, 3.0])).view(1, 2, 1, 2).requires_grad_()
    query = torch.tensor([[[1.0, 0.0]] * 2], requires_grad=True)
    bias = torch.zeros(1, 2, requires_grad=True)
    msg = match_and_select(query, bias, keys, torch.ones(1, 2, 1, DV),
                           torch.ones(1, 2, 1, dtype=torch.bool),
                           torch.ones(1, 2, dtype=torch.bool), CFG)
    assert (msg.omega[0, 0] == 0).all()  # s_00 = σ(-0.1) ≤ ½: closed
    msg.omega[0, 0].sum().backward()
    for t in (keys, query, bias):
        assert t.grad is not None and t.grad.abs().sum() > 0


def test_finished_agent_is_masked_out_of_matching():
    msg, _ = matched_round(3, active=torch.tensor([[True, False, True]]))
    assert (msg.scores[0, :, 1] == 0).all() and (msg.scores[0, 1] == 0).all()
    assert (msg.omega[0, 1] == 0).all()
    assert msg.bytes_sent[0, 1] == 0 and not msg.links[0, :, 1].any()
    # Agent 0 alone with agent 2 (key against its query): it reads itself only.
    assert torch.allclose(msg.scores[0, 0, 0], P) and msg.omega[0, 0].abs().sum() > 0
    assert not msg.links[0, 0].any()


def test_masked_memory_entries_are_ignored():
    keys = torch.randn(1, 2, 2, 2)
    values = torch.rand(1, 2, 2, DV)
    query = torch.randn(1, 2, 2)
    mask = torch.tensor([[[True, False], [True, True]]])
    active = torch.ones(1, 2, dtype=torch.bool)
    full = match_and_select(query, torch.zeros(1, 2), keys, values, mask, active, CFG)
    garbage = keys.clone()
    garbage[0, 0, 1] = 1e3
    other = match_and_select(query, torch.zeros(1, 2), garbage, values, mask, active, CFG)
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


def constant_scores(model: ActorCritic, logit: float) -> torch.Tensor:
    """Hand-set F_query, F_key and ψ so that every (query, entry) pair has ψ = σ(logit)."""
    comm = model.towers[0].comm
    v = torch.zeros(16)
    v[0] = 1.0
    u = F.layer_norm(v, (16,))  # μ = κ = u for every input
    with torch.no_grad():
        for layer in (comm.key, comm.query):
            layer.weight.zero_()
            layer.bias.copy_(v)
        comm.psi.weight.copy_(torch.eye(16))
        comm.psi_bias.fill_(logit - float(u @ u) / 4)  # μᵀWκ/√16 + b = logit
    return torch.sigmoid(torch.tensor(logit))


def run(model, cfg_n: int, steps: int, seed: int = 0, e: int = 1, active=None):
    state = model.initial_state(e, cfg_n)
    start = torch.ones(e, cfg_n, dtype=torch.bool)
    outs = []
    for t in range(steps):
        obs = observations(e, cfg_n, seed + t)
        if active is not None and t > 0:
            obs["active"] = active
        out = model(obs, state, start)
        outs.append(out)
        state, start = out.state, torch.zeros_like(start)
    return outs


@pytest.mark.parametrize("n", [2, 3, 4])
def test_model_in_eval_mode_puts_teammate_values_in_omega(n):
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    p = constant_scores(model, 1.0)
    out = run(model, n, 1, e=2)[0]
    values = out.state.mem_values[:, :, 0]  # υ of this step (stored at step 0)
    want = p * p * values.sum(dim=1, keepdim=True).expand_as(values)
    assert torch.allclose(out.message.omega, want, atol=1e-5)
    counts = communication_counts(out.message, torch.ones(2, n, dtype=torch.bool))
    assert counts.received.all() and counts.when.all()


def test_a_muted_model_reads_only_its_own_memory_and_sends_nothing():
    """The ``--mute`` ablation: same weights, teammates' entries out of the match."""
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    p = constant_scores(model, 1.0)
    talking = run(model, 3, 1, e=2)[0]
    model.listen = False
    out = run(model, 3, 1, e=2)[0]
    values = out.state.mem_values[:, :, 0]
    assert torch.equal(values, talking.state.mem_values[:, :, 0])  # same υ either way
    assert torch.allclose(out.message.omega, p * p * values, atol=1e-5)
    assert not torch.allclose(out.message.omega, talking.message.omega, atol=1e-3)
    counts = communication_counts(out.message, torch.ones(2, 3, dtype=torch.bool))
    assert counts.when.all() and not counts.received.any()
    assert (out.message.bytes_sent == 0).all() and (talking.message.bytes_sent > 0).all()
    # trained so (--model.comm.no-listen): the config's model starts deaf, same messages
    torch.manual_seed(0)
    deaf = ActorCritic(tiny(listen=False)).eval()
    assert not deaf.listen
    deaf.load_state_dict(model.state_dict())
    assert torch.equal(run(deaf, 3, 1, e=2)[0].message.omega, out.message.omega)


def test_a_critic_or_an_actor_that_does_not_hear_is_the_muted_model_in_that_half():
    """``--model.comm.no-critic-hears``: the actor's ω and actions are the talking
    model's, the critic's values are those of the same weights muted; and the other way
    round with ``--model.comm.no-actor-hears``."""
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    constant_scores(model, 1.0)  # every gate open: teammates' values reach every agent
    talking = run(model, 3, 3, e=2)
    model.listen = False
    muted = run(model, 3, 3, e=2)
    torch.manual_seed(0)
    blind = ActorCritic(tiny(critic_hears=False)).eval()
    blind.load_state_dict(model.state_dict())
    outs = run(blind, 3, 3, e=2)
    for t, out in enumerate(outs):
        assert torch.equal(out.message.omega, talking[t].message.omega)
        assert torch.equal(action_mean(out.dist), action_mean(talking[t].dist))
        torch.testing.assert_close(out.value, muted[t].value, rtol=0, atol=1e-6)
        assert not torch.allclose(out.value, talking[t].value, atol=1e-4)
    counts = communication_counts(outs[-1].message, torch.ones(2, 3, dtype=torch.bool))
    assert counts.received.all()
    # the other arm (--model.comm.no-actor-hears): the muted model's actions and the
    # talking model's values, and the messages the critic hears
    torch.manual_seed(0)
    deaf_actor = ActorCritic(tiny(actor_hears=False)).eval()
    deaf_actor.load_state_dict(model.state_dict())
    for t, out in enumerate(run(deaf_actor, 3, 3, e=2)):
        torch.testing.assert_close(action_mean(out.dist), action_mean(muted[t].dist),
                                   rtol=0, atol=1e-6)
        assert not torch.allclose(action_mean(out.dist), action_mean(talking[t].dist),
                                  atol=1e-4)
        assert torch.equal(out.value, talking[t].value)
        assert torch.equal(out.message.omega, talking[t].message.omega)


@pytest.mark.parametrize("critic_gradient", [True, False])
def test_the_value_loss_reaches_the_messages_only_with_critic_gradient(critic_gradient):
    torch.manual_seed(0)
    model = ActorCritic(tiny(critic_gradient=critic_gradient))
    constant_scores(model, 1.0)  # every gate open
    out = run(model, 2, 2)[-1]
    out.value.square().sum().backward()  # a value loss alone
    comm = model.towers[0].comm
    reached = [p.grad is not None and bool(p.grad.abs().sum() > 0) for p in comm.parameters()]
    assert any(reached) == critic_gradient
    model.zero_grad(set_to_none=True)
    out = run(model, 2, 2)[-1]
    out.dist.mean.square().sum().backward()  # the policy's path trains them either way
    assert any(p.grad is not None and bool(p.grad.abs().sum() > 0) for p in comm.parameters())


def test_model_matches_an_entry_stored_k_steps_earlier():
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    p = constant_scores(model, 1.0)
    outs = run(model, 2, 4)
    first, last = outs[0].state.mem_values[:, :, 0], outs[-1].state.mem_values
    assert torch.equal(last[:, :, 0], first)  # the step-0 entry is still in memory
    want = p * p * last[:, :, :4].mean(dim=2).sum(dim=1, keepdim=True)
    assert torch.allclose(outs[-1].message.omega, want.expand(1, 2, 24), atol=1e-5)


def test_model_agent_whose_teammates_finished_reads_its_own_memory():
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    p = constant_scores(model, 1.0)
    active = torch.tensor([[True, False, False]])
    out = run(model, 3, 3, active=active)[-1]
    assert out.state.mem_count.tolist() == [[3, 1, 1]]
    own = out.state.mem_values[0, 0, :3].mean(dim=0)
    assert torch.allclose(out.message.omega[0, 0], p * p * own, atol=1e-5)
    assert (out.message.omega[0, 1:] == 0).all()
    counts = communication_counts(out.message, active)
    assert counts.when.tolist() == [[True, False, False]] and not counts.received.any()


def test_model_with_self_scores_below_threshold_is_silent():
    torch.manual_seed(0)
    model = ActorCritic(tiny()).eval()
    constant_scores(model, -1.0)  # σ(-1) ≈ 0.27 ≤ η = ½
    for out in run(model, 2, 3, e=2):
        assert (out.message.omega == 0).all()
        counts = communication_counts(out.message, torch.ones(2, 2, dtype=torch.bool))
        assert not counts.received.any() and not counts.when.any()


def test_train_and_eval_give_the_same_omega():
    torch.manual_seed(4)  # an initialisation whose gates open on some steps, not all
    model = ActorCritic(tiny())
    trained, evaluated = run(model.train(), 3, 3, e=4), run(model.eval(), 3, 3, e=4)
    for a, b in zip(trained, evaluated, strict=True):
        assert torch.equal(a.message.omega, b.message.omega)
        assert torch.equal(a.message.links, b.message.links)
        assert torch.equal(a.dist.mean, b.dist.mean)
    opened = torch.stack([o.message.self_open for o in trained]).float().mean()
    assert 0 < opened < 1  # both states occur in this data


def test_policy_loss_gradients_reach_query_key_psi_and_value():
    torch.manual_seed(0)
    model = ActorCritic(tiny()).train()
    outs = run(model, 3, 2, e=4)
    g = torch.Generator().manual_seed(1)
    loss = sum(-(o.dist.log_prob(torch.randn(4, 3, 2, generator=g))
                 * torch.randn(4, 3, generator=g)).mean() for o in outs)
    assert isinstance(loss, torch.Tensor)
    loss.backward()
    comm = model.towers[0].comm
    for name, param in (("query", comm.query.weight), ("key", comm.key.weight),
                        ("psi", comm.psi.weight), ("psi_bias", comm.psi_bias),
                        ("value", comm.value[0].weight)):
        assert param.grad is not None and param.grad.abs().sum() > 0, name


def test_untrained_cpu_model_at_two_agents_both_talks_and_stays_silent():
    torch.manual_seed(3)
    model = ActorCritic(ModelConfig.cpu()).eval()
    e, n = 64, 2
    state, start = model.initial_state(e, n), torch.ones(e, n, dtype=torch.bool)
    received, when = [], []
    with torch.no_grad():
        for t in range(3):
            obs = observations(e, n, 100 + t, shape=(32, 128), goal=(32, 32))
            out = model(obs, state, start)
            state, start = out.state, torch.zeros_like(start)
            counts = communication_counts(out.message, obs["active"])
            received.append(counts.received)
            when.append(counts.when)
    received_rate = torch.stack(received).float().mean()
    when_rate = torch.stack(when).float().mean()
    assert 0 < received_rate < 1 and 0 < when_rate < 1


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
        # Same decisions; values to float rounding (CPU kernels vectorise by tensor size,
        # and the memory variant matches over 2 entries, one masked, instead of 1).
        assert torch.equal(a.message.links, b.message.links)
        assert torch.equal(a.message.self_open, b.message.self_open)
        assert torch.allclose(a.message.omega, b.message.omega, atol=1e-6)
        assert torch.allclose(a.dist.mean, b.dist.mean, atol=1e-6)
        assert torch.allclose(a.value, b.value, atol=1e-6)
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
    counts = communication_counts(out.message, torch.ones(1, 2, dtype=torch.bool))
    assert not counts.received.any() and not counts.when.any()


def test_configs_saved_with_the_retired_gate_field_are_refused_by_name():
    from collavn.configs import from_dict, to_dict
    from collavn.errors import ConfigError

    old = to_dict(ModelConfig.cpu())
    old["comm"]["gate"] = "auto"
    with pytest.raises(ConfigError, match=r"unknown config key comm\.gate"):
        from_dict(ModelConfig, old, "")
    with pytest.raises(ValueError, match="threshold"):
        CommConfig(threshold=1.0)


def _reference_rounds(model, o, s, state, starts, active):
    """The step-by-step ring buffer (write_memory), one step at a time, as a reference."""
    from collavn.models.communication import pooled_past_values

    tower, cfg = model.towers[0], model.cfg.comm
    keys, values = state.mem_keys, state.mem_values
    count, steps, omegas = state.mem_count, state.steps, []
    for t in range(starts.shape[0]):
        reset = starts[t]
        keys = torch.where(reset[..., None, None], 0.0, keys)
        values = torch.where(reset[..., None, None], 0.0, values)
        count = torch.where(reset, 0, count)
        steps = torch.where(reset, 0, steps)
        x = torch.cat([o[t], s[t]], dim=-1).flatten(0, 1)
        key, value = (v.view(*starts.shape[1:], -1) for v in tower.comm.key_value(x))
        write = active[t] & (steps % cfg.store_interval == 0)
        keys, values, count, slot = write_memory(keys, values, count, key, value, write)
        stored = memory_mask(count, keys.shape[2])
        pooled = pooled_past_values(values, stored & ~slot).flatten(0, 1)
        query, bias = tower.comm.query_psi(x, pooled)
        msg = match_and_select(
            query.view(*starts.shape[1:], -1), bias.view(starts.shape[1:]),
            torch.cat([keys, key.unsqueeze(2)], dim=2),
            torch.cat([values, value.unsqueeze(2)], dim=2),
            torch.cat([stored, ~write.unsqueeze(-1)], dim=2), active[t], cfg)
        omegas.append(msg.omega)
        steps = steps + active[t].long()
    return torch.stack(omegas), keys, values, count, steps


@pytest.mark.parametrize("slots,interval", [(3, 1), (2, 2), (80, 1)])
def test_a_sequence_matches_the_step_by_step_ring_buffer(slots, interval):
    torch.manual_seed(slots + interval)
    model = ActorCritic(tiny(memory_slots=slots, store_interval=interval)).eval()
    t_len, e, n = 9, 3, 3
    emb, sdim = model.towers[0].embed_size, model.towers[0].map_vector_size
    o, s = torch.randn(t_len, e, n, emb), torch.randn(t_len, e, n, sdim)
    starts = torch.zeros(t_len, e, n, dtype=torch.bool)
    starts[0] = True
    starts[5, 1] = True  # env 1 starts a new episode mid-sequence
    active = torch.ones(t_len, e, n, dtype=torch.bool)
    active[4:, 2, 0] = False  # agent 0 of env 2 finishes
    state = model.initial_state(e, n)
    with torch.no_grad():
        ref, keys, values, count, steps = _reference_rounds(model, o, s, state, starts, active)
        _, omega, critic_omega, after = model._communicate(o, s, state, starts, active)
        assert critic_omega is omega  # the critic hears what the actor hears by default
        assert torch.allclose(omega, ref, atol=1e-6) and ref.abs().sum() > 0
        assert torch.allclose(after.mem_keys, keys, atol=1e-6)
        assert torch.allclose(after.mem_values, values, atol=1e-6)
        assert torch.equal(after.mem_count, count) and torch.equal(after.steps, steps)
        # one step at a time (collection) gives the messages PPO's replay gives, to the
        # last bit or two: on AVX-512 CPUs torch's vectorised sigmoid rounds an element
        # by its place in the vector loop, and 9 steps at once place them differently
        # from one step (measured 3e-8 on AMD EPYC; bit-identical on other machines)
        one, state1 = [], state
        for t in range(t_len):
            _, w, _, state1 = model._communicate(o[t:t + 1], s[t:t + 1], state1,
                                                 starts[t:t + 1], active[t:t + 1])
            one.append(w[0])
    torch.testing.assert_close(torch.stack(one), omega, rtol=0, atol=1e-6)
    torch.testing.assert_close(state1.mem_values, after.mem_values, rtol=0, atol=1e-6)
    assert (count.max() > slots) == (slots < 80)  # the small buffers wrapped around


def test_entries_gradients_match_a_dense_gather():
    """entry_dot / entry_sum take their backward pass over table rows, not per entry."""
    from collavn.models.communication import Entries, entry_dot, entry_sum

    g = torch.Generator().manual_seed(0)
    t_len, e, m, rows, length, d = 3, 2, 2, 5, 4, 3
    table = torch.randn(e, m, rows, d, generator=g, dtype=torch.float64, requires_grad=True)
    index = torch.randint(0, rows, (t_len, e, m, length), generator=g)  # rows repeat
    query = torch.randn(t_len, e, m, d, generator=g, dtype=torch.float64, requires_grad=True)
    weight = torch.rand(t_len, e, m, m, length, generator=g, dtype=torch.float64,
                        requires_grad=True)
    entries = Entries(table, index)
    assert torch.autograd.gradcheck(lambda q, tb: entry_dot(q, Entries(tb, index)),
                                    (query, table))
    assert torch.autograd.gradcheck(lambda w, tb: entry_sum(w, Entries(tb, index)),
                                    (weight, table))
    # against autograd through the dense copy, with the rows shared by a gathered view
    dense = entries.dense()
    want = (torch.einsum("tend,temld->tenml", query, dense) ** 2).sum() + (
        torch.einsum("tenml,temld->tenmd", weight, dense) ** 3).sum()
    shared = entries.gathered()
    assert shared.rows is not None and not shared.rows.requires_grad
    got = (entry_dot(query, shared) ** 2).sum() + (entry_sum(weight, shared) ** 3).sum()
    torch.testing.assert_close(got, want)
    grads = torch.autograd.grad(want, (query, weight, table))
    for a, b in zip(torch.autograd.grad(got, (query, weight, table)), grads, strict=True):
        torch.testing.assert_close(a, b)
    with pytest.raises(TypeError, match="must both be dense tensors or both Entries"):
        match_and_select(query[0], torch.zeros(e, m), entries, dense[0], torch.ones(
            e, m, length, dtype=torch.bool), torch.ones(e, m, dtype=torch.bool), CFG)
