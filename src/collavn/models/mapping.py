"""Map building module F_map(O_t, p_{t-1:t}, S_{t-1}) → S_t and the map encoder.

Frames and image convention (shared with the env's ``gt_map``): a top-down grid is
drawn *heading up*: the frame's +x (forward) points to the top row, +y (left) to the
left column, and the origin sits at the grid centre. The local patch is in the agent's
current frame; the episode map S_t is in the agent's frame at ``t = 0`` (agent at the
centre, start heading up), so registering a patch is one rotate/translate by the pose
``(x, y, yaw)`` integrated from odometry, done with ``affine_grid``/``grid_sample``
(differentiable) and never re-warping the accumulated map (no blur over time).

S_t has ``4`` channels at ``resolution`` (obstacle probability, explored, past
trajectory, current location) plus ``feature_channels`` on a coarse ``feature_size``
grid over the same extent. Fusion: element-wise max for obstacle/explored/trajectory;
features are blended towards the current visual feature by the fraction of each coarse
cell seen at this step.

Who trains what: the local-map predictor (trunk and occupancy decoder) learns only from
the supervised :func:`map_loss` (the policy's gradients stop at its outputs when
``MapConfig.detach``). The visual-feature channels come from ``MapBuilder.feature_proj``
applied to the (detached) predictor trunk; the map loss has no target for them, so they
learn from the **policy loss** (PPO or imitation): their gradient flows through the
fused feature grid and :class:`MapEncoder` into the actor and critic, and the policy
optimizer holds ``feature_proj``'s weights (see ``collavn.training.map_training``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from collavn.models.config import MapConfig
from collavn.models.encoders import channels_last, make_encoder, with_depth

MAP_CHANNELS = 4  # obstacle, explored, trajectory, current location


def integrate_pose(pose: Tensor, delta: Tensor) -> Tensor:
    """Compose a pose with an odometry step.

    Args:
        pose: ``(B, 3)`` (x, y, yaw) of the agent in the episode-start frame.
        delta: ``(B, 3)`` (dx, dy, dyaw) in the agent's frame at the previous step.

    Returns:
        ``(B, 3)`` the new pose in the episode-start frame.
    """
    c, s = torch.cos(pose[:, 2]), torch.sin(pose[:, 2])
    x = pose[:, 0] + c * delta[:, 0] - s * delta[:, 1]
    y = pose[:, 1] + s * delta[:, 0] + c * delta[:, 1]
    yaw = torch.remainder(pose[:, 2] + delta[:, 2] + math.pi, 2 * math.pi) - math.pi
    return torch.stack([x, y, yaw], dim=1)


def register_theta(pose: Tensor, map_half: float, local_half: float) -> Tensor:
    """``(B, 2, 3)`` affine map from map-grid to local-patch normalised coordinates.

    With ``u`` the column and ``v`` the row coordinate in [-1, 1] (``align_corners=False``):
    a map point is ``X = -v·A, Y = -u·A`` metres, seen from the agent at ``pose`` at
    ``x_l = R(-yaw)(X - p)``, i.e. patch coordinates ``u_l = -y_l/B, v_l = -x_l/B``.
    """
    c, s = torch.cos(pose[:, 2]), torch.sin(pose[:, 2])
    px, py, r = pose[:, 0], pose[:, 1], map_half / local_half
    row0 = torch.stack([r * c, -r * s, (c * py - s * px) / local_half], dim=1)
    row1 = torch.stack([r * s, r * c, (c * px + s * py) / local_half], dim=1)
    return torch.stack([row0, row1], dim=1)


def egocentric_theta(pose: Tensor, map_half: float, window_half: float) -> Tensor:
    """``(B, 2, 3)`` affine map from an egocentric window to map normalised coordinates.

    The inverse of :func:`register_theta` (with the window in place of the patch).
    """
    c, s = torch.cos(pose[:, 2]), torch.sin(pose[:, 2])
    px, py, r = pose[:, 0], pose[:, 1], window_half / map_half
    row0 = torch.stack([r * c, r * s, -py / map_half], dim=1)
    row1 = torch.stack([-r * s, r * c, -px / map_half], dim=1)
    return torch.stack([row0, row1], dim=1)


def register_patch(patch: Tensor, pose: Tensor, map_size: int, resolution: float,
                   mode: str = "bilinear") -> Tensor:
    """Place an egocentric local patch into the episode map frame.

    Args:
        patch: ``(B, C, m, m)`` agent-centred, heading-up patch at ``resolution``.
        pose: ``(B, 3)`` agent pose in the episode-start frame.
        map_size: Cells per side of the output map.
        resolution: Metres per cell of both the patch and the map.
        mode: ``grid_sample`` interpolation (``bilinear`` or ``nearest``).

    Returns:
        ``(B, C, map_size, map_size)``; zero outside the patch footprint.
    """
    theta = register_theta(pose, map_size * resolution / 2, patch.shape[-1] * resolution / 2)
    size = (patch.shape[0], patch.shape[1], map_size, map_size)
    grid = F.affine_grid(theta.to(patch.dtype), list(size), align_corners=False)
    return F.grid_sample(patch, grid, mode=mode, padding_mode="zeros", align_corners=False)


def egocentric_window(grid_map: Tensor, pose: Tensor, out_size: int, window_m: float,
                      map_m: float, mode: str = "bilinear") -> Tensor:
    """Crop an agent-centred, heading-up window out of a map in the episode frame.

    Args:
        grid_map: ``(B, C, S, S)`` map covering ``map_m`` metres per side.
        pose: ``(B, 3)`` agent pose in the episode-start frame.
        out_size: Cells per side of the window.
        window_m: Metres per side covered by the window.
        map_m: Metres per side covered by ``grid_map``.
        mode: ``grid_sample`` interpolation.

    Returns:
        ``(B, C, out_size, out_size)``; zero where the window leaves the map.
    """
    theta = egocentric_theta(pose, map_m / 2, window_m / 2).to(grid_map.dtype)
    size = [grid_map.shape[0], grid_map.shape[1], out_size, out_size]
    grid = F.affine_grid(theta, size, align_corners=False)
    return F.grid_sample(grid_map, grid, mode=mode, padding_mode="zeros", align_corners=False)


def location_disk(pose: Tensor, map_size: int, resolution: float, radius: float) -> Tensor:
    """``(B, 1, S, S)`` float mask of the cells within ``radius`` metres of the agent."""
    half = map_size / 2
    centres = (half - torch.arange(map_size, device=pose.device, dtype=pose.dtype) - 0.5)
    centres = centres * resolution  # row i → X, column j → Y (both decrease downwards)
    dx = centres.view(1, -1, 1) - pose[:, 0].view(-1, 1, 1)
    dy = centres.view(1, 1, -1) - pose[:, 1].view(-1, 1, 1)
    reach = max(radius, resolution / 2)
    return ((dx * dx + dy * dy) <= reach * reach).to(pose.dtype).unsqueeze(1)


def map_loss(pred_logits: Tensor, gt: Tensor) -> Tensor:
    """Binary cross-entropy between predicted local patches and the env's ``gt_map``.

    Args:
        pred_logits: ``(..., 2, m, m)`` logits (obstacle, explored).
        gt: ``(..., 2, M, M)`` targets in [0, 1] over the same extent; when ``M ≠ m``
            they are area-resampled to ``m`` (e.g. a 10 cm ``gt_map`` for a 20 cm model).

    Returns:
        Scalar mean loss.
    """
    m, big = pred_logits.shape[-1], gt.shape[-1]
    pred = pred_logits.reshape(-1, 2, m, m)
    target = gt.reshape(-1, 2, big, big).to(pred.dtype)
    if big != m:
        target = F.interpolate(target, size=(m, m), mode="area")
    return F.binary_cross_entropy_with_logits(pred, target)


class LocalMapPredictor(nn.Module):
    """Panorama (and optional depth) → local patch logits and a visual feature vector."""

    def __init__(self, cfg: MapConfig, panorama_shape: tuple[int, int, int]) -> None:
        super().__init__()
        channels, h, w = panorama_shape
        self.cfg = cfg
        self.encoder = make_encoder(cfg.encoder, (channels + int(cfg.use_depth), h, w),
                                    cfg.hidden)
        self.seed = cfg.local_size // 8
        self.fc = nn.Sequential(nn.Linear(cfg.hidden, 64 * self.seed * self.seed), nn.ReLU())
        self.decoder = nn.Sequential(
            nn.ConvTranspose2d(64, 32, 4, 2, 1), nn.ReLU(),
            nn.ConvTranspose2d(32, 16, 4, 2, 1), nn.ReLU(),
            nn.ConvTranspose2d(16, 2, 4, 2, 1))
        self.output_size = cfg.hidden

    def forward(self, panorama: Tensor, depth: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Predict the local patch.

        Args:
            panorama: ``(B, 3, H, W)`` uint8.
            depth: ``(B, H, W)`` metres; required iff ``cfg.use_depth``.

        Returns:
            ``(B, 2, m, m)`` logits (obstacle, explored) and ``(B, hidden)`` features.
        """
        x = (with_depth(panorama, depth, self.cfg.max_depth, "MapConfig.use_depth")
             if self.cfg.use_depth else panorama)
        hidden = self.encoder(x)
        seed = self.fc(hidden).view(-1, 64, self.seed, self.seed)
        return self.decoder(seed), hidden


@dataclass(frozen=True)
class MapStep:
    """One step of F_map for a batch of B agents.

    Attributes:
        grid: ``(B, 4, S, S)`` the updated map S_t.
        features: ``(B, F, G, G)`` the updated visual-feature grid.
        pose: ``(B, 3)`` pose in the episode-start frame.
        logits: ``(B, 2, m, m)`` the local patch prediction (for :func:`map_loss`).
        seen: ``(B, 1, G, G)`` fraction of each feature cell seen at this step (how far
            the feature grid moved towards this step's visual feature).
    """

    grid: Tensor
    features: Tensor
    pose: Tensor
    logits: Tensor
    seen: Tensor


class MapBuilder(nn.Module):
    """F_map: predict the local patch, register it with the pose, fuse it into S_{t-1}.

    ``predictor`` is trained by :func:`map_loss`; ``feature_proj`` (trunk features →
    ``feature_channels``) by the policy loss.
    """

    def __init__(self, cfg: MapConfig, panorama_shape: tuple[int, int, int]) -> None:
        super().__init__()
        self.cfg = cfg
        self.predictor = LocalMapPredictor(cfg, panorama_shape)
        self.feature_proj = nn.Sequential(nn.Linear(cfg.hidden, cfg.feature_channels),
                                          nn.ReLU())

    def forward(self, panorama: Tensor, depth: Tensor | None, pose_delta: Tensor,
                grid: Tensor, features: Tensor, pose: Tensor, first: Tensor) -> MapStep:
        """One map update for ``B`` agents: :meth:`predict` then :meth:`update`.

        Args:
            panorama: ``(B, 3, H, W)`` uint8.
            depth: ``(B, H, W)`` or ``None``.
            pose_delta: ``(B, 3)`` odometry since the previous step (ignored if ``first``).
            grid: ``(B, 4, S, S)`` S_{t-1} (zeros at an episode start).
            features: ``(B, F, G, G)`` previous feature grid.
            pose: ``(B, 3)`` previous pose.
            first: ``(B,)`` bool, this observation starts an episode (pose := 0).
        """
        logits, hidden = self.predict(panorama, depth)
        return self.update(logits, hidden, pose_delta, grid, features, pose, first)

    def predict(self, panorama: Tensor, depth: Tensor | None) -> tuple[Tensor, Tensor]:
        """The local-map predictor alone: logits ``(B, 2, m, m)``, trunk ``(B, hidden)``.

        With ``cfg.detach`` no policy gradient reaches the predictor (:meth:`update`
        detaches), so its outputs for a stored step stay valid until the predictor's own
        next update: a rollout stores them (see ``ActorCritic.stored_percepts``).
        """
        return self.predictor(panorama, depth)

    def update(self, logits: Tensor, hidden: Tensor, pose_delta: Tensor, grid: Tensor,
               features: Tensor, pose: Tensor, first: Tensor) -> MapStep:
        """Register and fuse a predicted local patch (from :meth:`predict`) into S_{t-1}."""
        grid_t, seen, new_pose = self.track(logits, pose_delta, grid, pose, first)
        features_t = blend_features(features, seen, self.visual(hidden))
        return MapStep(grid_t, features_t, new_pose, logits, seen)

    def track(self, logits: Tensor, pose_delta: Tensor, grid: Tensor, pose: Tensor,
              first: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """The map channels and the pose of :meth:`update`: new grid, ``seen``, pose.

        With ``cfg.detach`` this has no parameters on its path (a rollout can store its
        results); the visual features are :meth:`visual` and :func:`blend_features`.
        """
        probs = torch.sigmoid(logits)
        if self.cfg.detach:  # the predictor learns from map_loss only
            probs = probs.detach()
        new_pose = integrate_pose(pose, pose_delta)
        new_pose = torch.where(first.unsqueeze(1), torch.zeros_like(new_pose), new_pose)
        grid_t, seen = self.fuse_grid(probs, new_pose, grid)
        return grid_t, seen, new_pose

    def visual(self, hidden: Tensor) -> Tensor:
        """This step's visual feature ``(B, F)`` from the predictor trunk.

        It learns from the policy loss (the trunk only from ``map_loss`` when
        ``cfg.detach``).
        """
        return self.feature_proj(hidden.detach() if self.cfg.detach else hidden)

    def fuse(self, local: Tensor, visual: Tensor, pose: Tensor, grid: Tensor,
             features: Tensor, mode: str = "bilinear") -> tuple[Tensor, Tensor]:
        """Register a local patch at ``pose`` and fuse it with the previous map.

        Args:
            local: ``(B, 2, m, m)`` obstacle / explored probabilities (agent frame).
            visual: ``(B, F)`` visual feature of this step.
            pose: ``(B, 3)`` current pose in the episode-start frame.
            grid: ``(B, 4, S, S)`` previous map.
            features: ``(B, F, G, G)`` previous feature grid.
            mode: Interpolation used for the registration.

        Returns:
            The new ``grid`` and ``features``.
        """
        new_grid, seen = self.fuse_grid(local, pose, grid, mode)
        return new_grid, blend_features(features, seen, visual)

    def fuse_grid(self, local: Tensor, pose: Tensor, grid: Tensor,
                  mode: str = "bilinear") -> tuple[Tensor, Tensor]:
        """The parameter-free part of :meth:`fuse`: the new grid and the seen fraction.

        Returns:
            The new ``grid`` ``(B, 4, S, S)`` and ``seen`` ``(B, 1, G, G)``, the fraction
            of each feature cell the registered patch covers.
        """
        cfg = self.cfg
        placed = register_patch(local, pose, cfg.size, cfg.resolution, mode)
        here = location_disk(pose, cfg.size, cfg.resolution, cfg.agent_radius)
        new_grid = torch.cat([
            torch.maximum(grid[:, :2], placed),
            torch.maximum(grid[:, 2:3], here),
            here,
        ], dim=1)
        return new_grid, F.adaptive_avg_pool2d(placed[:, 1:2], cfg.feature_size)


def blend_features(features: Tensor, seen: Tensor, visual: Tensor) -> Tensor:
    """Move each feature cell towards ``visual`` ``(B, F)`` by its ``seen`` fraction.

    ``features`` ``(B, F, G, G)`` (or any leading shape with ``seen`` ``(..., 1, G, G)``
    and ``visual`` ``(..., F)`` alike).
    """
    return features + seen * (visual[..., None, None] - features)


class MapEncoder(nn.Module):
    """S_t → a vector for the policy, from an egocentric (heading-up) view of the map."""

    def __init__(self, cfg: MapConfig) -> None:
        super().__init__()
        self.cfg = cfg
        k = cfg.encoder_size // 8
        c1, c2, c3 = cfg.encoder_channels
        self.grid_net = nn.Sequential(
            nn.Conv2d(MAP_CHANNELS, c1, 3, 2, 1), nn.ReLU(),
            nn.Conv2d(c1, c2, 3, 2, 1), nn.ReLU(),
            nn.Conv2d(c2, c3, 3, 2, 1), nn.ReLU(), nn.Flatten(),
            nn.Linear(c3 * k * k, cfg.embed_dim), nn.ReLU())
        self.feature_net = nn.Sequential(
            nn.Conv2d(cfg.feature_channels, 32, 1), nn.ReLU(), nn.Flatten(),
            nn.Linear(32 * cfg.feature_size ** 2, cfg.embed_dim), nn.ReLU())
        self.out = nn.Sequential(nn.Linear(2 * cfg.embed_dim, cfg.embed_dim), nn.ReLU())
        self.output_size = cfg.embed_dim

    def forward(self, grid: Tensor, features: Tensor, pose: Tensor) -> Tensor:
        """``(B, 4, S, S)``, ``(B, F, G, G)``, ``(B, 3)`` → ``(B, embed_dim)``."""
        return self.encode(self.grid_window(grid, pose), self.feature_window(features, pose))

    def grid_window(self, grid: Tensor, pose: Tensor) -> Tensor:
        """The egocentric window of the map channels, ``(B, 4, e, e)`` (no parameters)."""
        extent = self.cfg.size * self.cfg.resolution
        return egocentric_window(grid, pose, self.cfg.encoder_size, extent, extent)

    def feature_window(self, features: Tensor, pose: Tensor) -> Tensor:
        """The egocentric window of the feature grid, ``(B, F, G, G)`` (no parameters)."""
        extent = self.cfg.size * self.cfg.resolution
        return egocentric_window(features, pose, self.cfg.feature_size, extent, extent)

    def encode(self, grid_window: Tensor, feature_window: Tensor) -> Tensor:
        """The trained part: the two egocentric windows → ``(B, embed_dim)``."""
        return self.out(torch.cat([self.grid_net(channels_last(grid_window)),
                                   self._feature_vector(feature_window)], dim=1))

    def _feature_vector(self, window: Tensor) -> Tensor:
        """``feature_net`` with its 1×1 convolution done as a matrix product per cell.

        The same weights and numbers up to rounding, but a 1×1 convolution rounds
        differently for batches under 16 than for larger ones, while the matrix product
        over ``B·G·G ≥ 8`` cells does not: one step at collection and all steps replayed
        at once by PPO then give bit-identical results.
        """
        conv, _, _, linear, _ = self.feature_net
        assert isinstance(conv, nn.Conv2d) and isinstance(linear, nn.Linear)
        cells = F.linear(window.permute(0, 2, 3, 1), conv.weight.flatten(1), conv.bias)
        return F.relu(linear(F.relu(cells).permute(0, 3, 1, 2).flatten(1)))
