"""Memory-augmented handshake communication: request / match / select / store.

Our reading of Sec. 4.2 of the paper, equation by equation, for the agents ``n`` of one
environment (everything batched as ``(E, N, ...)``; ``d`` = ``key_dim``):

* **request** — κ_n = F_key(x_n), υ_n = F_value(x_n) with x_n = [O_n, S_n];
  μ_n = F_query(x_n, avgpool(υ_n^{past})). One-layer MLPs (affine for μ and κ, affine +
  ReLU for υ). avgpool(υ^{past}) is the mean of the values held in memory *other than*
  the current one (zeros if none). μ and κ, and x where they read it, are layer-normalised
  (no weights): μᵀWκ/√d is then O(1) at initialisation and depends on the content of x
  rather than on the shared positive offset of its ReLU features. Without this it starts
  near 0, i.e. ψ ≈ σ(0) = ½, which at N = 2 *is* η: every gate would hang on the sign of
  an input-independent 10⁻³.
* **store** — (κ_n, υ_n) is written into the agent's private ring-buffer memory
  ``(E, N, T, d)`` (``memory``: every ``store_interval`` steps, FIFO once ``T`` slots are
  full; ``handshake``: never). The current entry is always matched, stored or not, so a
  one-slot memory behaves exactly like ``handshake``.
* **match** — every (query, key entry) pair is scored on its own, in [0, 1]:
  ψ(μ_n, κ_m^{t'}) = σ(μ_nᵀ W κ_m^{t'} / √d + b), W and b learnable (one ψ per
  requester's weights). Over the entries t' of agent m (itself included):
  s_{n,m} = mean_{t'} ψ(μ_n, κ_m^{t'}) and υ̂_{n,m} = mean_{t'} ψ(μ_n, κ_m^{t'}) υ_m^{t'}.
  No softmax across agents: one pair's score never depends on another pair's, so at
  every N any pair can pass the threshold or stay below it.
* **select** — Γ(s, η) = s·[s > η] with η = 1/N, N the *active* agents of the
  environment (``CommConfig.threshold`` replaces it when set). A lone agent (its
  teammates finished, or N = 1) uses η = ½: with η = 1 no score in [0, 1] could pass
  and it could never read its own memory. The self gate o_n = [s_{n,n} > η] decides
  *when*; the supporter gates [s_{n,m} > η] decide *who*:

      ω_n = o_n · (s_{n,n} υ̂_{n,n} + Σ_{m≠n} Γ(s_{n,m}, η) υ̂_{n,m}),

  so ω_n = 0 when Γ(s_{n,n}) = 0.
* **gradients** — the gate is the same hard indicator in ``train()`` and ``eval()``
  (same ω); its backward pass is the gradient of σ((s − η)/temperature)
  (straight-through), so the loss reaches F_query, F_key, ψ and F_value through closed
  gates too.

Bandwidth per agent and step (``bytes_per_float`` each): its query (``query_dim``) when
its own gate opens (s_{n,n} needs only its own memory, so a silent agent broadcasts
nothing); one score back to every other active agent that broadcast a query; and its
value υ̂ (``value_dim``) over every link on which it was selected.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Any, cast

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.autograd.function import once_differentiable

from collavn.models.config import CommConfig


class CommProjections(nn.Module):
    """F_query, F_key, F_value and the learnable score ψ of one agent (or all, shared)."""

    def __init__(self, cfg: CommConfig, input_size: int) -> None:
        super().__init__()
        self.cfg = cfg
        self.key = nn.Linear(input_size, cfg.key_dim)
        self.value = nn.Sequential(nn.Linear(input_size, cfg.value_dim), nn.ReLU())
        self.query = nn.Linear(input_size + cfg.value_dim, cfg.query_dim)
        self.psi = nn.Linear(cfg.query_dim, cfg.key_dim, bias=False)
        self.psi_bias = nn.Parameter(torch.zeros(()))
        nn.init.normal_(self.psi.weight, std=cfg.key_dim ** -0.5)  # ψ logits ~ N(0, 1)
        self.output_size = cfg.value_dim

    def key_value(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``(B, input_size)`` → κ ``(B, key_dim)`` (normalised), υ ``(B, value_dim)``."""
        return _normalise(self.key(_normalise(x))), self.value(x)

    def query_psi(self, x: Tensor, pooled: Tensor) -> tuple[Tensor, Tensor]:
        """``(B, input_size)``, ``(B, value_dim)`` → Wᵀμ ``(B, key_dim)``, b ``(B,)``."""
        query = _normalise(self.query(torch.cat([_normalise(x), pooled], dim=1)))
        return self.psi(query), self.psi_bias.expand(query.shape[0])


def _normalise(x: Tensor) -> Tensor:
    """Zero mean, unit variance over the last dimension (a layer norm without weights)."""
    return F.layer_norm(x, x.shape[-1:])


@dataclass(frozen=True)
class Message:
    """Result of one communication round.

    Attributes:
        omega: ``(E, N, value_dim)`` the message ω given to the policy and the critic.
        scores: ``(E, N, N)`` agent scores s_{n,m} in [0, 1] (rows: requester n; zero
            where n or m is inactive).
        gates: ``(E, N, N)`` the weights of υ̂_{n,m} in ω_n: o_n·s_{n,n} on the
            diagonal, o_n·Γ(s_{n,m}) elsewhere (carry the straight-through gradient).
        self_open: ``(E, N)`` bool, the agent's own gate opened (Γ(s_{n,n}) > 0): *when*.
        links: ``(E, N, N)`` bool, ``links[e, n, m]``: m's value entered ω_n (m ≠ n).
        bytes_sent: ``(E, N)`` bytes transmitted by each agent this step.
    """

    omega: Tensor
    scores: Tensor
    gates: Tensor
    self_open: Tensor
    links: Tensor
    bytes_sent: Tensor


@dataclass(frozen=True)
class CommCounts:
    """Per agent-step communication statistics (see :func:`communication_counts`).

    Attributes:
        received: ``(E, N)`` bool, at least one teammate's value entered ω_n.
        when: ``(E, N)`` bool, the agent's own gate opened.
        bytes: ``(E, N)`` float, bytes the agent sent.
    """

    received: Tensor
    when: Tensor
    bytes: Tensor


def communication_counts(message: Message, active: Tensor) -> CommCounts:
    """Who received, who opened its gate, and the traffic, for every agent-step.

    Rates over active agent-steps are ``counts.received[active].float().mean()`` (and
    so on); inactive agents count as neither receiving nor sending.

    Args:
        message: One communication round (ω of shape ``(E, N, value_dim)``).
        active: ``(E, N)`` bool, the agents that acted this step.

    Returns:
        ``received``, ``when`` ``(E, N)`` bool and ``bytes`` ``(E, N)`` float.
    """
    active = active.bool()
    received = message.links.any(dim=-1) & message.self_open & active
    when = message.self_open & active
    return CommCounts(received, when, message.bytes_sent * active)


@dataclass(frozen=True)
class Entries:
    """The entries each of ``T`` steps matches, as rows of one table.

    Entry ``l`` of agent ``m`` at step ``t`` is ``table[e, m, index[t, e, m, l]]``. A
    replay of ``T`` steps matches each against its whole memory: as one dense tensor that
    is ``T·L`` copies of the table's rows, and its gradient as many again (at the ``cpu``
    preset 5 million floats per PPO mini-batch, most of the update's communication
    cost). :func:`entry_dot` and :func:`entry_sum` gather the rows in their forward pass
    only — with the arithmetic of a dense tensor, so a step gives the same bits at
    collection and in a replay — and run their backward pass over the table's ``R`` rows.

    Attributes:
        table: ``(E, M, R, d)``.
        index: ``(T, E, M, L)`` int64 rows of ``table``.
        rows: ``None``, or :meth:`dense` computed once (:meth:`gathered`) for several
            forward passes to share; it carries no gradient, the table does.
    """

    table: Tensor
    index: Tensor
    rows: Tensor | None = None

    @classmethod
    def of(cls, dense: Tensor) -> Entries:
        """One step whose entries are ``dense`` ``(E, M, L, d)`` itself."""
        e, m, length = dense.shape[:3]
        index = torch.arange(length, device=dense.device).expand(1, e, m, length)
        return cls(dense, index)

    def dense(self) -> Tensor:
        """Every step's entries, ``(T, E, M, L, d)`` (a copy)."""
        return _gather_rows(self.table, self.index)

    def gathered(self) -> Entries:
        """The same entries with :attr:`rows` filled in."""
        with torch.no_grad():
            return replace(self, rows=self.dense())

    def step(self, t: int) -> Tensor:
        """Step ``t``'s entries ``(E, M, L, d)``."""
        return _gather_rows(self.table, self.index[t:t + 1 or None])[0]


def _gather_rows(table: Tensor, index: Tensor) -> Tensor:
    """``(E, M, R, d)`` table, ``(T, E, M, L)`` rows → ``(T, E, M, L, d)``."""
    t, e, m, length = index.shape
    rows, d = table.shape[2:]
    base = torch.arange(e * m, device=table.device).view(1, e, m, 1) * rows
    flat = table.reshape(e * m * rows, d).index_select(0, (index + base).flatten())
    return flat.view(t, e, m, length, d)


def _einsum_rows(spec: str, x: Tensor, table: Tensor, index: Tensor,
                 rows: Tensor | None) -> Tensor:
    """``einsum(spec)`` of ``(T, E, ...)`` ``x`` and the gathered rows, as ``T·E`` envs.

    The forward pass of :func:`entry_dot` and :func:`entry_sum`: one batch of ``T·E``
    envs, the arithmetic of one step at collection (``rows``: already gathered).
    """
    rows = _gather_rows(table, index) if rows is None else rows
    out = torch.einsum(spec, x.flatten(0, 1), rows.flatten(0, 1))
    return out.unflatten(0, x.shape[:2])


def _scatter_rows(x: Tensor, index: Tensor, rows: int) -> Tensor:
    """``(T, E, N, M, L)`` per entry → ``(T, E, N, M, R)`` per table row (summed)."""
    out = x.new_zeros(*x.shape[:-1], rows)
    return out.scatter_add_(-1, index.unsqueeze(2).expand_as(x), x)


class _EntryDot(torch.autograd.Function):
    """``z[t, e, n, m, l] = query[t, e, n] · table[e, m, index[t, e, m, l]]``."""

    @staticmethod
    def forward(ctx: Any, query: Tensor, table: Tensor, index: Tensor,
                rows: Tensor | None) -> Tensor:
        ctx.save_for_backward(query, table, index)
        return _einsum_rows("end,emld->enml", query, table, index, rows)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, Tensor | None, None, None]:
        query, table, index = ctx.saved_tensors
        rows = _scatter_rows(grad, index, table.shape[2])
        grad_query = (torch.einsum("tenmr,emrd->tend", rows, table)
                      if ctx.needs_input_grad[0] else None)
        grad_table = (torch.einsum("tenmr,tend->emrd", rows, query)
                      if ctx.needs_input_grad[1] else None)
        return grad_query, grad_table, None, None


class _EntrySum(torch.autograd.Function):
    """``out[t, e, n, m] = Σ_l weight[t, e, n, m, l] · table[e, m, index[t, e, m, l]]``."""

    @staticmethod
    def forward(ctx: Any, weight: Tensor, table: Tensor, index: Tensor,
                rows: Tensor | None) -> Tensor:
        ctx.save_for_backward(weight, table, index)
        return _einsum_rows("enml,emld->enmd", weight, table, index, rows)

    @staticmethod
    @once_differentiable
    def backward(ctx: Any, grad: Tensor) -> tuple[Tensor | None, Tensor | None, None, None]:
        weight, table, index = ctx.saved_tensors
        grad_weight = grad_table = None
        if ctx.needs_input_grad[0]:
            per_row = torch.einsum("tenmd,emrd->tenmr", grad, table)
            grad_weight = per_row.gather(-1, index.unsqueeze(2).expand_as(weight))
        if ctx.needs_input_grad[1]:
            rows = _scatter_rows(weight, index, table.shape[2])
            grad_table = torch.einsum("tenmr,tenmd->emrd", rows, grad)
        return grad_weight, grad_table, None, None


def entry_dot(query: Tensor, entries: Entries) -> Tensor:
    """``(T, E, N, d)`` queries · every entry → ``(T, E, N, M, L)`` (see :class:`Entries`)."""
    return cast(Tensor, _EntryDot.apply(query, entries.table, entries.index,
                                          entries.rows))


def entry_sum(weight: Tensor, entries: Entries) -> Tensor:
    """``(T, E, N, M, L)`` weights → ``(T, E, N, M, d)`` weighted sums of the entries."""
    return cast(Tensor, _EntrySum.apply(weight, entries.table, entries.index,
                                          entries.rows))


def memory_mask(count: Tensor, slots: int) -> Tensor:
    """``(E, N)`` writes so far → ``(E, N, slots)`` bool, slot holds an entry."""
    idx = torch.arange(slots, device=count.device)
    return idx < count.clamp(max=slots).unsqueeze(-1)


def pooled_past_values(values: Tensor | Entries, mask: Tensor) -> Tensor:
    """Masked mean over entries.

    Dense ``(E, N, L, dv)`` values and an ``(E, N, L)`` mask give ``(E, N, dv)``;
    :class:`Entries` of ``T`` steps and a ``(T, E, N, L)`` mask give ``(T, E, N, dv)``.
    """
    if not isinstance(values, Entries):
        return pooled_past_values(Entries.of(values), mask[None])[0]
    w = mask.to(values.table.dtype)
    total = entry_sum(w.unsqueeze(2), values)[:, :, 0]  # (T, E, N, dv)
    return total / w.sum(dim=-1, keepdim=True).clamp(min=1.0)


def selection_threshold(active: Tensor, cfg: CommConfig) -> Tensor:
    """η per environment, ``(E, N)`` bool → ``(E,)``: ``cfg.threshold`` or 1/max(N, 2)."""
    if cfg.threshold is not None:
        return torch.full(active.shape[:1], cfg.threshold, device=active.device)
    return 1.0 / active.sum(dim=1).clamp(min=2).float()


def straight_through_gate(scores: Tensor, eta: Tensor, temperature: float) -> Tensor:
    """Forward: the indicator [s > η]; backward: the gradient of σ((s − η)/temperature).

    Args:
        scores: ``(E, N, N)`` agent scores.
        eta: ``(E, 1, 1)`` thresholds.
        temperature: Width of the surrogate sigmoid.
    """
    soft = torch.sigmoid((scores - eta) / temperature)
    return (scores > eta).to(scores.dtype) + (soft - soft.detach())


def match_scores(query_psi: Tensor, bias: Tensor, keys: Entries, values: Entries,
                 entry_mask: Tensor, pair_active: Tensor) -> tuple[Tensor, Tensor]:
    """ψ over every (requester, entry) pair, averaged over each agent's entries.

    Args:
        query_psi: ``(T, E, N, dk)`` queries with ψ's matrix applied (Wᵀμ).
        bias: ``(T, E, N)`` ψ's bias b (of the requester's weights).
        keys: :class:`Entries` of ``T`` steps, ``L`` keys of each agent (memory + current).
        values: :class:`Entries` of the same rows, ``dv`` wide.
        entry_mask: ``(T, E, N, L)`` bool, entry present.
        pair_active: ``(T, E, N, N)`` bool, requester and supporter both active.

    Returns:
        s ``(T, E, N, N)`` = mean_{t'} ψ and υ̂ ``(T, E, N, N, dv)`` = mean_{t'} ψ·υ.
    """
    z = entry_dot(query_psi, keys) / math.sqrt(keys.table.shape[-1])  # (T, E, N, M, L)
    psi = torch.sigmoid(z + bias[..., None, None])
    weight = psi * entry_mask.unsqueeze(2).to(psi.dtype)
    n_entries = entry_mask.sum(dim=-1).clamp(min=1).to(psi.dtype).unsqueeze(2)  # (T, E, 1, M)
    weight = weight / n_entries.unsqueeze(-1) * pair_active.unsqueeze(-1).to(psi.dtype)
    return weight.sum(dim=-1), entry_sum(weight, values)


def match_and_select(query_psi: Tensor, bias: Tensor, keys: Tensor | Entries,
                     values: Tensor | Entries, entry_mask: Tensor, active: Tensor,
                     cfg: CommConfig, teammates: bool = True) -> Message:
    """Match every requester against every active agent's entries and form ω.

    One step from dense entries, or ``T`` steps at once from :class:`Entries` (then
    every other argument, and every field of the message, has a leading ``T`` axis).

    Args:
        query_psi: ``(E, N, dk)`` queries with ψ's matrix applied (Wᵀμ).
        bias: ``(E, N)`` ψ's bias b (of the requester's weights).
        keys: ``(E, N, L, dk)`` entries of each agent (memory + current).
        values: ``(E, N, L, dv)``.
        entry_mask: ``(E, N, L)`` bool, entry present.
        active: ``(E, N)`` bool; inactive agents neither request nor support.
        cfg: Communication settings (threshold, temperature, sizes).
        teammates: ``False`` cuts every link between two agents (an ablation): each
            agent matches only its own memory, η and its own gate stay as they are, and
            nothing is sent or received.
    """
    if isinstance(keys, Tensor) and isinstance(values, Tensor):
        one = match_and_select(query_psi[None], bias[None], Entries.of(keys),
                               Entries.of(values), entry_mask[None], active[None], cfg,
                               teammates)
        return Message(*(f[0] for f in _message_fields(one)))
    if not isinstance(keys, Entries) or not isinstance(values, Entries):
        raise TypeError("keys and values must both be dense tensors or both Entries")
    steps, e, n = active.shape
    eye = torch.eye(n, dtype=torch.bool, device=active.device)
    pair_active = active.unsqueeze(3) & active.unsqueeze(2)
    if not teammates:
        pair_active = pair_active & eye
    scores, v_hat = match_scores(query_psi, bias, keys, values, entry_mask, pair_active)
    scores, v_hat = scores.flatten(0, 1), v_hat.flatten(0, 1)
    active, pair_active = active.flatten(0, 1), pair_active.flatten(0, 1)
    eta = selection_threshold(active, cfg).to(scores.dtype).view(-1, 1, 1)
    opened = straight_through_gate(scores, eta, cfg.temperature)
    self_gate = torch.diagonal(opened, dim1=1, dim2=2)  # o_n: the *when* decision
    gates = scores * torch.where(eye, torch.ones_like(opened), opened)
    gates = gates * self_gate.unsqueeze(-1)
    omega = torch.einsum("enm,enmd->end", gates, v_hat)

    above = (scores > eta) & pair_active
    self_open = torch.diagonal(above, dim1=1, dim2=2)
    links = above & self_open.unsqueeze(-1) & ~eye
    sent = (_bytes_sent(links, self_open, active, cfg) if teammates
            else torch.zeros(active.shape, device=active.device))
    fields = (omega, scores, gates, self_open, links, sent)
    return Message(*(f.unflatten(0, (steps, e)) for f in fields))


def hearing_margin(scores: Tensor, active: Tensor, cfg: CommConfig) -> tuple[Tensor, Tensor]:
    """How far each agent is from hearing a teammate: min(s_{n,n}, max_{m≠n} s_{n,m}) − η.

    A teammate's value reaches agent ``n`` exactly when its own gate opens (s_{n,n} > η)
    and so does the link to at least one active teammate (s_{n,m} > η): when this margin
    is > 0. Differentiable in the scores (min and max pass the gradient to one of them).

    Args:
        scores: ``(..., N, N)`` the agents' scores (:attr:`Message.scores`).
        active: ``(..., N)`` bool.
        cfg: Communication settings (η).

    Returns:
        The margin ``(..., N)`` and a mask ``(..., N)`` of the agents it means anything
        for: active, with at least one active teammate.
    """
    n = active.shape[-1]
    flat = active.reshape(-1, n)
    eta = selection_threshold(flat, cfg).to(scores.dtype).reshape(*active.shape[:-1], 1)
    eye = torch.eye(n, dtype=torch.bool, device=scores.device)
    teammate = active.unsqueeze(-2) & ~eye  # (..., N, N): column m active, m ≠ n
    best = scores.masked_fill(~teammate, float("-inf")).amax(dim=-1)
    own = torch.diagonal(scores, dim1=-2, dim2=-1)
    has_teammate = active & teammate.any(dim=-1)
    margin = torch.minimum(own, best.masked_fill(~has_teammate, 0.0)) - eta
    return margin, has_teammate


def _message_fields(message: Message) -> tuple[Tensor, ...]:
    """A message's fields in order (``dataclasses.astuple`` would deep-copy tensors)."""
    return tuple(getattr(message, f.name) for f in fields(message))


def _bytes_sent(links: Tensor, self_open: Tensor, active: Tensor, cfg: CommConfig) -> Tensor:
    """``(E, N)`` bytes each agent transmits: query + scores + values over its links."""
    requests = self_open.sum(dim=1, keepdim=True) - self_open.long()  # other requesters
    floats = self_open * cfg.query_dim + active * requests
    floats = floats + links.sum(dim=1) * cfg.value_dim  # column m: links where m sends
    return (floats * cfg.bytes_per_float).to(torch.float32)


def silent_message(active: Tensor, value_dim: int, dtype: torch.dtype) -> Message:
    """The ``none`` variant's round: an empty ω and no traffic."""
    e, n = active.shape
    zeros = torch.zeros(e, n, n, dtype=dtype, device=active.device)
    return Message(torch.zeros(e, n, value_dim, dtype=dtype, device=active.device), zeros,
                   zeros, torch.zeros_like(active, dtype=torch.bool), zeros.bool(),
                   torch.zeros(e, n, device=active.device))


@dataclass(frozen=True)
class MemoryPlan:
    """Where every step of a sequence reads and writes the agents' memories.

    The memory is a function of the keys and values of earlier steps and of integer
    bookkeeping only (episode starts, active flags, the store schedule), so a sequence of
    ``T`` steps needs no step-by-step state: each step's memory *after its write* is a
    gather from a source table ``[memory before the sequence (S slots) | this sequence's
    entries (T) | a zero row]`` (:meth:`gather`). It holds exactly what a step-by-step
    ring buffer would hold, slot for slot (write at slot ``count % S``, overwriting the
    oldest; tested against such a reference).

    Attributes:
        index: ``(T, E, N, S)`` int64, row of the source table in each slot after step t.
        write: ``(T, E, N)`` bool, the step's entry is stored.
        count: ``(T, E, N)`` int64, writes since the episode start after step t.
        steps: ``(E, N)`` int64, steps since the episode start after the last step.
    """

    index: Tensor
    write: Tensor
    count: Tensor
    steps: Tensor

    @property
    def slot(self) -> Tensor:
        """``(T, E, N, S)`` bool, one-hot of the slot step t wrote (its own table row)."""
        t_len = self.index.shape[0]
        own = self.index.shape[3] + torch.arange(t_len, device=self.index.device)
        return self.index == own.view(t_len, 1, 1, 1)

    def entries(self, before: Tensor, new: Tensor) -> Entries:
        """What each step matches: its memory after the write, then its own entry.

        ``(E, N, S, d)`` memory before, ``(T, E, N, d)`` new entries → :class:`Entries`
        with ``L = S + 1`` (entry ``S`` is step t's own, stored or not) over the table
        ``[memory before | new entries | a zero row]``: no copies of whole memories per
        step.
        """
        t, e, n, s = self.index.shape
        table = torch.cat([before, new.permute(1, 2, 0, 3), new.new_zeros(e, n, 1, new.shape[-1])],
                          dim=2)  # (E, N, S + T + 1, d)
        own = (s + torch.arange(t, device=table.device)).view(t, 1, 1, 1).expand(t, e, n, 1)
        return Entries(table, torch.cat([self.index, own], dim=3))


def plan_memory(count: Tensor, steps: Tensor, starts: Tensor, active: Tensor, slots: int,
                store_interval: int, writes: bool) -> MemoryPlan:
    """The :class:`MemoryPlan` of ``T`` steps from the state before them.

    Args:
        count: ``(E, N)`` writes since the episode start, before the first step.
        steps: ``(E, N)`` steps since the episode start, before the first step.
        starts: ``(T, E, N)`` bool, the step begins an episode (its memory is cleared
            first).
        active: ``(T, E, N)`` bool; an inactive agent neither writes nor counts a step.
        slots: Ring-buffer slots S (0: nothing is ever stored).
        store_interval: Store every this many steps.
        writes: The variant stores entries at all (``memory``).
    """
    t_len = starts.shape[0]
    zero_row = slots + t_len
    current = torch.arange(slots, device=count.device).expand(*count.shape, slots).clone()
    count, steps = count.clone(), steps.clone()
    index, write_all, count_all = [], [], []
    for t in range(t_len):
        reset = starts[t]
        count = torch.where(reset, torch.zeros_like(count), count)
        steps = torch.where(reset, torch.zeros_like(steps), steps)
        current = torch.where(reset[..., None], torch.full_like(current, zero_row), current)
        write = active[t] & (steps % store_interval == 0) & (writes and slots > 0)
        if slots:
            slot = (torch.arange(slots, device=count.device) == (count % slots)[..., None]
                    ) & write[..., None]
            current = torch.where(slot, torch.full_like(current, slots + t), current)
        count = count + write.long()
        steps = steps + active[t].long()
        index.append(current)
        write_all.append(write)
        count_all.append(count)
    return MemoryPlan(torch.stack(index), torch.stack(write_all), torch.stack(count_all),
                      steps)
