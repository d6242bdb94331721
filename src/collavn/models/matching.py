"""Goal matching: where around the agent does the goal image's content appear, and how big?

A goal image is a front view taken at the goal pose; the agent's panorama (heading at the
centre column) shows the same surfaces from elsewhere, shifted in azimuth and scaled by
the change of distance. :class:`GoalMatcher` turns that into an explicit input instead of
leaving a GRU to discover the comparison from two pooled embeddings:

1. one small convolutional trunk (shared by both images) maps panorama and goal to
   feature grids at stride 4, and the stride-4 average of the normalised RGB is appended
   (so colour matching works from the first step, before any training);
2. the goal grid is resized to each of ``scales`` (1 = the same angular size as in the
   goal image; < 1 = content seen from farther away) and slid around the panorama's
   central rows with wrap-around — a cosine similarity per azimuth and scale;
3. the ``(scales, W/4)`` similarity profile goes through a linear layer to a vector.

The profile is egocentric (index ``W/8`` is straight ahead), so rolling the panorama by
``k`` feature columns rolls the profile by ``k`` (tested). Not in the paper: the ``cpu``
preset uses it to learn something in an hour of CPU time; the ``paper`` preset leaves it
off.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from collavn.models.config import MatchConfig
from collavn.models.encoders import channels_last, normalise_rgb

STRIDE = 4


class GoalMatcher(nn.Module):
    """Azimuth × scale similarity of the goal image to the panorama, then a linear layer."""

    def __init__(self, cfg: MatchConfig, panorama_shape: tuple[int, int, int],
                 goal_shape: tuple[int, int, int]) -> None:
        super().__init__()
        _, ph, pw = panorama_shape
        _, gh, gw = goal_shape
        for name, (h, w) in (("panorama", (ph, pw)), ("goal", (gh, gw))):
            if h % STRIDE or w % STRIDE:
                raise ValueError(f"{name} height and width must be multiples of {STRIDE} "
                                 f"for goal matching, got {h}×{w}")
        self.grid_h, self.grid_w = ph // STRIDE, pw // STRIDE
        self.goal_hw = (gh // STRIDE, gw // STRIDE)
        self.channels = cfg.channels  # learned + pooled RGB
        learned = cfg.channels - 3  # MatchConfig ensures ≥ 1
        self.trunk = nn.Sequential(
            nn.Conv2d(3, learned, 5, 2, 2), nn.ReLU(inplace=True),
            nn.Conv2d(learned, learned, 3, 2, 1))
        self.template_hw = [self._template_hw(s) for s in cfg.scales]
        self.head = nn.Sequential(nn.Linear(len(cfg.scales) * self.grid_w, cfg.output_size),
                                  nn.ReLU())
        self.output_size = cfg.output_size

    def _template_hw(self, scale: float) -> tuple[int, int]:
        h = max(1, min(self.grid_h, round(self.goal_hw[0] * scale)))
        w = max(1, min(self.grid_w, round(self.goal_hw[1] * scale)))
        return h, w

    def features(self, images: Tensor, wrap: bool = False) -> Tensor:
        """``(B, 3, H, W)`` uint8 → ``(B, channels, H/4, W/4)`` (learned + pooled RGB).

        ``wrap``: the image is a 360° panorama; pad it around in azimuth so the
        features of the first and last columns see their true neighbours.
        """
        x = normalise_rgb(images[:, :3])
        if not wrap:
            return torch.cat([self.trunk(channels_last(x)), F.avg_pool2d(x, STRIDE)], dim=1)
        pad = 2 * STRIDE  # ≥ the trunk's reach; a whole number of feature columns
        x = torch.cat([x[..., -pad:], x, x[..., :pad]], dim=-1)
        feats = torch.cat([self.trunk(channels_last(x)), F.avg_pool2d(x, STRIDE)], dim=1)
        return feats[..., pad // STRIDE:-(pad // STRIDE)]

    def profile(self, panorama: Tensor, goal: Tensor) -> Tensor:
        """Cosine similarities ``(B, len(scales), W/4)``; column ``W/8`` is straight ahead.

        Both the template and each panorama window are centred (mean over channels and
        cells) before the cosine, so a uniform brightness offset does not match.
        """
        return self._profile(self.features(panorama, wrap=True), self.templates(goal))

    @property
    def ring_channels(self) -> int:
        """Channels of :meth:`match`'s ring: every row's features, then the profile."""
        return self.channels * self.grid_h + len(self.template_hw)

    def templates(self, goal: Tensor) -> list[Tensor]:
        """The goal image's features at each scale, centred: ``(B, channels, h_s, w_s)``.

        They depend on the goal image only, so a caller that sees the same goal for many
        steps can compute them once (:class:`~collavn.models.frames.FramePerception`
        does) and pass them to :meth:`match`.
        """
        feats = self.features(goal)
        out = []
        for h, w in self.template_hw:
            t = F.interpolate(feats, size=(h, w), mode="bilinear", align_corners=False)
            out.append(t - t.mean(dim=(1, 2, 3), keepdim=True))
        return out

    def match(self, panorama: Tensor, goal: Tensor | list[Tensor]
              ) -> tuple[Tensor, Tensor]:
        """The match vector ``(B, output_size)`` and the **ring** ``(B, ring_channels, W/4)``.

        ``goal``: the goal images, or their :meth:`templates`. The ring is what the
        panorama shows in each feature column — the features of all its rows (so the
        height of the floor's edge, i.e. the distance to a wall, is there) — with the
        goal's similarity profile in that column. It is egocentric like the profile:
        rolling the panorama by ``k`` feature columns rolls it by ``k``.
        """
        pano = self.features(panorama, wrap=True)
        prof = self._profile(pano, goal if isinstance(goal, list) else self.templates(goal))
        ring = torch.cat([pano.flatten(1, 2), prof], dim=1)
        return self.head(prof.flatten(1)), ring

    def _profile(self, pano: Tensor, templates: list[Tensor]) -> Tensor:
        b, c = pano.shape[:2]
        out = []
        for t in templates:
            h, w = t.shape[-2:]
            top = (self.grid_h - h) // 2
            rows = pano[:, :, top:top + h]
            left = w // 2  # window centred on each column, wrapping around
            rows = torch.cat([rows[..., self.grid_w - left:], rows,
                              rows[..., :w - 1 - left]], dim=-1)
            # Σ window·t (t has zero mean, so centring the window changes nothing)
            dot = F.conv2d(rows.reshape(1, b * c, h, -1), t, groups=b).reshape(b, -1)
            n = c * h * w
            total = F.avg_pool2d(rows.sum(1, keepdim=True), (h, w), 1).reshape(b, -1) * (h * w)
            sq = F.avg_pool2d(rows.pow(2).sum(1, keepdim=True), (h, w), 1).reshape(b, -1)
            var = (sq * (h * w) - total.pow(2) / n).clamp_min(0.0)
            norm = var.sqrt() * t.pow(2).sum(dim=(1, 2, 3)).sqrt()[:, None]
            out.append(dot / (norm + 1e-6))
        return torch.stack(out, dim=1)

    def forward(self, panorama: Tensor, goal: Tensor) -> Tensor:
        """``(B, output_size)`` match vector."""
        return self.match(panorama, goal)[0]
