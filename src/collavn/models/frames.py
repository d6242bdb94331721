"""Per-frame perception: what one step's panorama and goal image say, before any memory.

:class:`FramePerception` holds the panorama encoder, the goal encoder and the goal
matcher and turns ``(panorama, goal)`` into ``o`` (the panorama embedding) and ``g`` (the
goal embedding, with the match vector appended when goal matching is on). It is the part
of the agent that :mod:`collavn.perception` pretrains on simulator labels and that a
training run can freeze (``collavn train --encoder``): frozen, its outputs depend on the
step's images only, so they are computed once at collection and stored in the rollout.

:class:`~collavn.models.policy.AgentTower` *is* a ``FramePerception`` (subclass), so a
pretrained encoder's state dict has exactly the tower's parameter names
(``panorama_encoder.*``, ``goal_encoder.*``, ``goal_matcher.*``).
"""

from __future__ import annotations

import itertools
from typing import Any

import torch
from torch import Tensor, nn

from collavn.models.config import ModelConfig
from collavn.models.encoders import make_encoder, with_depth
from collavn.models.matching import GoalMatcher
from collavn.models.readout import PerceptionReadout, RingReadout

#: Layers whose training mode changes state or output; :meth:`FramePerception.goal_features`
#: does not reuse results while one of them is in training mode.
_MODAL = (nn.modules.batchnorm._BatchNorm, nn.modules.dropout._DropoutNd)

#: Submodules of :class:`FramePerception` (prefixes of its state-dict keys).
FRAME_MODULES = ("panorama_encoder", "goal_encoder", "goal_matcher", "readout")


def frame_spec(cfg: ModelConfig) -> dict[str, Any]:
    """The fields of a model config that fix :class:`FramePerception`'s weights' shapes.

    A pretrained encoder fits a model iff these are equal (JSON-compatible values).
    """
    return {"encoder": cfg.encoder, "embed_dim": cfg.embed_dim,
            "panorama_shape": list(cfg.panorama_shape), "goal_shape": list(cfg.goal_shape),
            **({"frame_depth": True} if cfg.frame_depth else {}),
            "goal_match": {"enabled": cfg.goal_match.enabled,
                           "channels": cfg.goal_match.channels,
                           "scales": list(cfg.goal_match.scales),
                           "output_size": cfg.goal_match.output_size},
            **({"readout": {"bins": cfg.readout.bins, "hidden": cfg.readout.hidden,
                            **({"ring": True} if cfg.readout.ring else {})}}
               if cfg.readout.enabled else {})}


class FramePerception(nn.Module):
    """Panorama encoder, goal encoder, (optional) goal matcher and perception readout."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        emb = cfg.embed_dim
        channels, h, w = cfg.panorama_shape
        self.frame_depth, self.max_depth = cfg.frame_depth, cfg.map.max_depth
        self.panorama_encoder = make_encoder(cfg.encoder,
                                             (channels + int(cfg.frame_depth), h, w), emb,
                                             cfg.weights_path)
        self.goal_encoder = make_encoder(cfg.encoder, cfg.goal_shape, emb, cfg.weights_path)
        self.goal_matcher = (GoalMatcher(cfg.goal_match, cfg.panorama_shape, cfg.goal_shape)
                             if cfg.goal_match.enabled else None)
        self.embed_size = emb
        #: Width of ``g`` before the readout (what the readout's pair head reads).
        self.pair_goal_size = emb + (0 if self.goal_matcher is None
                                     else self.goal_matcher.output_size)
        r = cfg.readout
        self.readout: PerceptionReadout | RingReadout | None = None
        if r.enabled and r.ring:
            assert self.goal_matcher is not None  # ModelConfig checks
            self.readout = RingReadout(self.goal_matcher.ring_channels,
                                       self.goal_matcher.grid_w, emb, self.pair_goal_size,
                                       r.bins, r.hidden)
        elif r.enabled:
            self.readout = PerceptionReadout(emb, self.pair_goal_size, r.bins, r.hidden)
        self.goal_size = self.pair_goal_size + r.size
        #: :meth:`goal_features`' last result: key, goals, embedding, templates.
        self._goal_cache: tuple[Any, Tensor, Tensor, list[Tensor] | None] | None = None

    def see(self, panorama: Tensor, goal: Tensor, depth: Tensor | None = None
            ) -> tuple[Tensor, Tensor]:
        """``(B, 3, H, W)``, ``(B, 3, Hg, Wg)`` uint8 → o ``(B, embed)``, g ``(B, goal_size)``.

        ``g`` is the goal embedding, then the match vector (goal matching), then the
        readout's features (perception readout). ``depth (B, H, W)`` metres is read
        (and required) iff ``ModelConfig.frame_depth``.
        """
        o, g, ring = self.see_pair(panorama, goal, depth)
        if self.readout is not None:
            g = torch.cat([g, self.readout.features(o, g, ring)], dim=1)
        return o, g

    def see_pair(self, panorama: Tensor, goal: Tensor, depth: Tensor | None = None
                 ) -> tuple[Tensor, Tensor, Tensor | None]:
        """What the readout reads: ``o``, ``g`` (without the readout's features), ring.

        The ring is the goal matcher's (``None`` without goal matching); the matcher
        compares RGB with RGB, so depth enters through the panorama encoder only.
        """
        o = self.panorama_encoder(
            with_depth(panorama, depth, self.max_depth, "ModelConfig.frame_depth")
            if self.frame_depth else panorama)
        g, templates = self.goal_features(goal)
        ring = None
        if self.goal_matcher is not None:
            assert templates is not None
            match, ring = self.goal_matcher.match(panorama, templates)
            g = torch.cat([g, match], dim=1)
        return o, g, ring

    def goal_features(self, goal: Tensor) -> tuple[Tensor, list[Tensor] | None]:
        """The goal encoder's embedding and the matcher's templates (``None``: no matcher).

        A goal image is fixed for an episode, and collection and evaluation see the same
        batch of goals for many steps. So without gradients the last batch's result is
        kept and returned again while the goals, the weights (each parameter's storage
        and version counter) and the modes stay the same; any change — a new episode in
        one env, an optimizer step, ``load_state_dict``, a move to another device —
        recomputes the whole batch. Results are therefore bit-identical to recomputing
        every step (tested), and the goal encoder runs about once per episode instead
        of once per step. The returned tensors are the kept ones: read them, do not
        modify them in place.
        """
        if torch.is_grad_enabled() or not self._goal_cacheable():
            return self._compute_goal_features(goal)
        key = self._goal_key()
        hit = self._goal_cache
        if (hit is not None and hit[0] == key and hit[1].shape == goal.shape
                and hit[1].dtype == goal.dtype and hit[1].device == goal.device
                and torch.equal(hit[1], goal)):
            return hit[2], hit[3]
        emb, templates = self._compute_goal_features(goal)
        self._goal_cache = (key, goal.clone(), emb, templates)
        return emb, templates

    def _compute_goal_features(self, goal: Tensor) -> tuple[Tensor, list[Tensor] | None]:
        return (self.goal_encoder(goal),
                None if self.goal_matcher is None else self.goal_matcher.templates(goal))

    def _goal_modules(self) -> list[nn.Module]:
        return [self.goal_encoder] + ([] if self.goal_matcher is None else [self.goal_matcher])

    def _goal_cacheable(self) -> bool:
        """No layer of the goal path changes state or output by mode (batch norm, dropout)."""
        return not any(m.training and isinstance(m, _MODAL) for top in self._goal_modules()
                       for m in top.modules())

    def _goal_key(self) -> tuple[tuple[int, int], ...]:
        return tuple((t.data_ptr(), t._version) for top in self._goal_modules()
                     for t in itertools.chain(top.parameters(), top.buffers()))

    def frame_modules(self) -> list[nn.Module]:
        """The submodules named in :data:`FRAME_MODULES` that exist."""
        return [m for name in FRAME_MODULES if (m := getattr(self, name)) is not None]

    def frame_state_dict(self) -> dict[str, Tensor]:
        """The state dict of the frame modules only (keys as in the full module)."""
        return {k: v.detach().clone() for k, v in self.state_dict().items()
                if k.split(".", 1)[0] in FRAME_MODULES}
