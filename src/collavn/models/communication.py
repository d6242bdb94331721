"""Memory-augmented handshake communication: request / match / select / store.

Every step, for the agents ``n`` of one environment (all batched as ``(E, N, ...)``):

* **request** — κ_n = F_key(x_n), υ_n = F_value(x_n) with x_n = [O_n, S_n];
  μ_n = F_query(x_n, avgpool(υ_n^{past})); μ_n is broadcast. One-layer MLPs (affine for
  μ and κ, affine + ReLU for υ).
* **store** — (κ_n, υ_n) is written into the agent's private ring-buffer memory
  ``(E, N, T, d)`` (``memory``: every ``store_interval`` steps, FIFO once ``T`` slots
  are full; ``handshake``: never). The current entry is always matched, stored or not,
  so a one-slot memory behaves exactly like ``handshake``; avgpool(υ^{past}) is the
  mean of the values held in memory *other than* the current one (zeros if none).
* **match** — z_{n,m,t'} = ψ(μ_n, κ_m^{t'}) = μ_nᵀ W κ_m^{t'} / √d_k over every entry of
  every active agent m (itself included). Normalisation: the agent score is
  s_{n,m} = softmax_m(log mean_{t'} exp z_{n,m,t'}), so Σ_m s_{n,m} = 1 over the active
  agents and η = 1/N means "above a uniform share"; υ̂_{n,m} = Σ_{t'} softmax_{t'}(z) υ_m^{t'}
  (the paper's mean_{t'} s·υ with the agent score factored out, see below).
* **select** — Γ(s) = s·[s > η] (hard) or s·σ((s − η)/τ) (soft); the self gate
  o_n = [s_{n,n} > η] (or σ(...)) decides *when*: ω_n = o_n Σ_m Γ(s_{n,m}) υ̂_{n,m}, so
  no message is formed when s_{n,n} ≤ η, and a supporter with s_{n,m} ≤ η sends nothing.

Bandwidth per sender and step (``bytes_per_float`` each): its query (``query_dim``)
when active, one score back to every other active agent, and its value (``value_dim``)
over every link selected by the hard rule (also reported in soft mode).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from collavn.models.config import CommConfig

_NEG = -1e9


class CommProjections(nn.Module):
    """F_query, F_key, F_value and the learnable score ψ of one agent (or all, shared)."""

    def __init__(self, cfg: CommConfig, input_size: int) -> None:
        super().__init__()
        self.cfg = cfg
        self.key = nn.Linear(input_size, cfg.key_dim)
        self.value = nn.Sequential(nn.Linear(input_size, cfg.value_dim), nn.ReLU())
        self.query = nn.Linear(input_size + cfg.value_dim, cfg.query_dim)
        self.psi = nn.Linear(cfg.query_dim, cfg.key_dim, bias=False)
        if cfg.query_dim == cfg.key_dim:
            nn.init.eye_(self.psi.weight)
        self.output_size = cfg.value_dim

    def key_value(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """``(B, input_size)`` → κ ``(B, key_dim)``, υ ``(B, value_dim)``."""
        return self.key(x), self.value(x)

    def query_psi(self, x: Tensor, pooled: Tensor) -> Tensor:
        """``(B, input_size)``, ``(B, value_dim)`` → Wᵀμ ``(B, key_dim)`` (ψ applied)."""
        return self.psi(self.query(torch.cat([x, pooled], dim=1)))


@dataclass(frozen=True)
class Message:
    """Result of one communication round.

    Attributes:
        omega: ``(E, N, value_dim)`` the message ω given to the policy and the critic.
        scores: ``(E, N, N)`` normalised scores s_{n,m} (rows: requester n).
        gates: ``(E, N, N)`` Γ(s) times the requester's self gate (what weights υ̂).
        links: ``(E, N, N)`` bool, m sends its value to n (hard rule, m ≠ n).
        bytes_sent: ``(E, N)`` bytes transmitted by each agent this step.
    """

    omega: Tensor
    scores: Tensor
    gates: Tensor
    links: Tensor
    bytes_sent: Tensor


def memory_mask(count: Tensor, slots: int) -> Tensor:
    """``(E, N)`` writes so far → ``(E, N, slots)`` bool, slot holds an entry."""
    idx = torch.arange(slots, device=count.device)
    return idx < count.clamp(max=slots).unsqueeze(-1)


def write_memory(keys: Tensor, values: Tensor, count: Tensor, new_key: Tensor,
                 new_value: Tensor, write: Tensor) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Append one entry per agent to a ring buffer (overwriting the oldest when full).

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


def pooled_past_values(values: Tensor, mask: Tensor) -> Tensor:
    """Masked mean over slots: ``(E, N, T, dv)``, ``(E, N, T)`` → ``(E, N, dv)``."""
    w = mask.to(values.dtype)
    total = (values * w.unsqueeze(-1)).sum(dim=2)
    return total / w.sum(dim=2, keepdim=True).clamp(min=1.0)


def match_and_select(query_psi: Tensor, keys: Tensor, values: Tensor, entry_mask: Tensor,
                     active: Tensor, cfg: CommConfig, hard: bool) -> Message:
    """Match every requester against every active agent's entries and form ω.

    Args:
        query_psi: ``(E, N, dk)`` queries with ψ's matrix applied (Wᵀμ).
        keys: ``(E, N, L, dk)`` entries of each agent (memory + current).
        values: ``(E, N, L, dv)``.
        entry_mask: ``(E, N, L)`` bool, entry present.
        active: ``(E, N)`` bool; inactive agents neither request nor support.
        cfg: Communication settings (threshold, temperature, sizes).
        hard: Use the hard gate (evaluation) instead of the soft one.
    """
    n_agents = keys.shape[1]
    z = torch.einsum("end,emld->enml", query_psi, keys) / math.sqrt(keys.shape[-1])
    valid = (entry_mask & active.unsqueeze(-1)).unsqueeze(1)  # (E, 1, M, L)
    z = z.masked_fill(~valid, _NEG)
    n_entries = valid.sum(dim=-1).clamp(min=1).to(z.dtype)  # (E, 1, M)
    agent_logit = torch.logsumexp(z, dim=-1) - torch.log(n_entries)
    agent_logit = agent_logit.masked_fill(~active.unsqueeze(1), _NEG)
    pair_active = active.unsqueeze(2) & active.unsqueeze(1)
    scores = torch.softmax(agent_logit, dim=-1) * pair_active  # (E, N, M)
    within = torch.softmax(z, dim=-1)  # (E, N, M, L)
    v_hat = torch.einsum("enml,emld->enmd", within, values)

    n_active = active.sum(dim=1).clamp(min=1).to(z.dtype)
    eta = (torch.full_like(n_active, cfg.threshold) if cfg.threshold is not None
           else 1.0 / n_active).view(-1, 1, 1)
    above = scores > eta
    soft_open = torch.sigmoid((scores - eta) / cfg.temperature)
    opened = above.to(z.dtype) if hard else soft_open
    gate = scores * opened
    self_open = torch.diagonal(opened, dim1=1, dim2=2)  # o_n: the *when* decision
    eye = torch.eye(n_agents, dtype=torch.bool, device=keys.device)
    gate = gate * self_open.unsqueeze(-1)
    omega = torch.einsum("enm,enmd->end", gate, v_hat)

    self_above = torch.diagonal(above, dim1=1, dim2=2)
    links = above & self_above.unsqueeze(-1) & pair_active & ~eye
    return Message(omega, scores, gate, links, _bytes_sent(links, active, cfg))


def _bytes_sent(links: Tensor, active: Tensor, cfg: CommConfig) -> Tensor:
    """``(E, N)`` bytes each agent transmits: query + scores + values over its links."""
    n_active = active.sum(dim=1, keepdim=True)
    floats = active * (cfg.query_dim + (n_active - 1).clamp(min=0))
    floats = floats + links.sum(dim=1) * cfg.value_dim  # column m: links where m sends
    return (floats * cfg.bytes_per_float).to(torch.float32)


def silent_message(active: Tensor, value_dim: int, dtype: torch.dtype) -> Message:
    """The ``none`` variant's round: an empty ω and no traffic."""
    e, n = active.shape
    zeros = torch.zeros(e, n, n, dtype=dtype, device=active.device)
    return Message(torch.zeros(e, n, value_dim, dtype=dtype, device=active.device), zeros,
                   zeros, zeros.bool(), torch.zeros(e, n, device=active.device))
