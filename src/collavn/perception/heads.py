"""Targets, losses and accuracies of the pretraining heads.

The heads are :class:`~collavn.models.readout.PerceptionReadout` on top of the frame
perception's ``o`` and ``g``: the model's own readout when ``model.readout`` is on (the
encoder file then carries them into training), else a separate one discarded after.

Losses: cross-entropy over ``bins`` sectors for the path and goal bearings, smooth-L1 on
``log(1 + metres)`` for the geodesic distance and per-sector free space. Held-out
accuracies: a bearing is right within one sector (±360°/K); a distance within
``max(0.5 m, 25 %)``; a sector's free space within ``max(0.25 m, 25 %)``.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F
from torch import Tensor

from collavn.models.readout import LABELS

__all__ = ["LABELS", "accuracies", "losses", "pair_hits", "targets"]


def targets(batch: Mapping[str, Tensor], bins: int, max_distance: float) -> dict[str, Tensor]:
    """Tensor targets from :func:`~collavn.perception.frames.sample_batch` output.

    ``reachable`` masks the pair labels of goals the panorama cannot reach.
    """
    width = batch["free"].shape[-1]
    reachable = torch.isfinite(batch["distance"]) & torch.isfinite(batch["path_column"])

    def sector(column: Tensor) -> Tensor:
        return (torch.nan_to_num(column).remainder(width) * bins / width).long() % bins

    free = batch["free"].float().reshape(len(reachable), bins, width // bins).amin(-1)
    return {"reachable": reachable,
            "path_bearing": sector(batch["path_column"]),
            "goal_bearing": sector(batch["goal_column"]),
            "distance": torch.log1p(torch.nan_to_num(batch["distance"].float(),
                                                     posinf=max_distance)
                                    .clamp(max=max_distance)),
            "free_space": torch.log1p(free)}


def losses(pred: Mapping[str, Tensor], target: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """Per-label losses (pair labels masked to reachable pairs)."""
    ok = target["reachable"].float()
    n = ok.sum().clamp(min=1.0)
    out = {k: (F.cross_entropy(pred[k], target[k], reduction="none") * ok).sum() / n
           for k in ("path_bearing", "goal_bearing")}
    out["distance"] = (F.smooth_l1_loss(pred["distance"], target["distance"],
                                        reduction="none") * ok).sum() / n
    out["free_space"] = F.smooth_l1_loss(pred["free_space"], target["free_space"])
    return out


def pair_hits(pred: Mapping[str, Tensor], target: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """Per pair, whether each pair label is right (see the module docstring).

    ``(B,)`` bool for the path bearing, the goal bearing and the distance; meaningful only
    where the goal is reachable.
    """
    out: dict[str, Tensor] = {}
    for k in ("path_bearing", "goal_bearing"):
        bins = pred[k].shape[-1]
        gap = (pred[k].argmax(-1) - target[k]).remainder(bins)
        out[k] = (gap <= 1) | (gap >= bins - 1)
    d_pred, d_true = torch.expm1(pred["distance"]), torch.expm1(target["distance"])
    out["distance"] = (d_pred - d_true).abs() <= torch.maximum(torch.full_like(d_true, 0.5),
                                                               0.25 * d_true)
    return out


def accuracies(pred: Mapping[str, Tensor], target: Mapping[str, Tensor]) -> dict[str, Tensor]:
    """Per-label fraction right in a batch (see the module docstring)."""
    ok = target["reachable"]
    out = {k: right[ok].float().mean() if ok.any() else torch.tensor(float("nan"))
           for k, right in pair_hits(pred, target).items()}
    f_pred, f_true = torch.expm1(pred["free_space"]), torch.expm1(target["free_space"])
    out["free_space"] = ((f_pred - f_true).abs()
                         <= torch.maximum(torch.full_like(f_true, 0.25), 0.25 * f_true)
                         ).float().mean()
    return out
