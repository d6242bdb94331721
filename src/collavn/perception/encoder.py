"""The pretrained encoder file (``encoder.pt``) and installing it, frozen, into a model.

One ``torch.save`` dict, written atomically: ``format`` (:data:`ENCODER_FORMAT`),
``spec`` — what the weights fit (:func:`collavn.models.frames.frame_spec` plus the
camera height the frames were rendered at), ``state_dict`` — the frame perception's
weights (``panorama_encoder.*``, ``goal_encoder.*``, ``goal_matcher.*``), ``metrics`` —
held-out accuracy per label, ``config`` — the pretraining config, ``steps``.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import torch
from torch import Tensor

from collavn.errors import CheckpointError
from collavn.files import atomic_write
from collavn.models.config import ModelConfig
from collavn.models.frames import FramePerception, frame_spec
from collavn.models.policy import ActorCritic

ENCODER_FORMAT = "collavn-encoder/1"


def encoder_spec(model: ModelConfig, camera_height: float) -> dict[str, Any]:
    """What a pretrained encoder must agree with to be used by a model."""
    return {**frame_spec(model), "camera_height": camera_height}


@dataclass(frozen=True)
class EncoderFile:
    """A loaded ``encoder.pt``.

    Attributes:
        path: Where it was read from.
        sha256: Checksum of the file's bytes.
        spec: :func:`encoder_spec` of the model it was made for.
        state_dict: The frame perception's weights.
        metrics: Held-out accuracy per label (and losses).
    """

    path: Path
    sha256: str
    spec: dict[str, Any]
    state_dict: dict[str, Tensor]
    metrics: dict[str, float]


def file_sha256(path: str | Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def save_encoder(path: str | Path, frames: FramePerception, spec: dict[str, Any],
                 metrics: dict[str, float], config: dict[str, Any], steps: int) -> Path:
    """Write ``encoder.pt`` atomically."""
    payload = {"format": ENCODER_FORMAT, "spec": spec, "state_dict": frames.frame_state_dict(),
               "metrics": metrics, "config": config, "steps": steps}
    return atomic_write(path, lambda f: torch.save(payload, f))


def load_encoder(path: str | Path) -> EncoderFile:
    """Read an ``encoder.pt``; :class:`CheckpointError` if it is not one."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no encoder file at {path} (make one with collavn pretrain)")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as e:  # torch raises many kinds on a corrupt file
        raise CheckpointError(f"cannot read encoder {path}: {e}") from e
    if not isinstance(payload, dict) or payload.get("format") != ENCODER_FORMAT:
        raise CheckpointError(f"{path} is not a collavn pretrained encoder "
                              f"({ENCODER_FORMAT}; made by collavn pretrain)")
    return EncoderFile(path, file_sha256(path), payload["spec"], payload["state_dict"],
                       dict(payload.get("metrics", {})))


def _images(spec: dict[str, Any]) -> str:
    c, h, w = spec["panorama_shape"]
    _, gh, gw = spec["goal_shape"]
    return f"{c}×{h}×{w} panoramas and {gh}×{gw} goal images"


def check_encoder(encoder: EncoderFile, model: ModelConfig, camera_height: float) -> None:
    """Refuse an encoder made for other images, camera or perception sizes."""
    want = encoder_spec(model, camera_height)
    have = encoder.spec
    if (have.get("panorama_shape"), have.get("goal_shape")) != (want["panorama_shape"],
                                                                want["goal_shape"]):
        raise CheckpointError(
            f"encoder {encoder.path} was pretrained on {_images(have)}; this run uses "
            f"{_images(want)}. Pretrain one for these sizes (collavn pretrain with the same "
            f"--preset and --panorama-width/--panorama-height/--goal-size) or train at its "
            f"sizes")
    diffs = [f"{k}: encoder {json.dumps(have.get(k))} vs run {json.dumps(v)}"
             for k, v in want.items() if have.get(k) != v]
    if diffs:
        raise CheckpointError(f"encoder {encoder.path} does not fit this model "
                              f"({'; '.join(diffs)}); pretrain with the same preset and "
                              f"model flags")


def install_encoder(model: ActorCritic, encoder: EncoderFile, camera_height: float) -> None:
    """Check ``encoder`` against ``model``, load it into every tower and freeze it."""
    check_encoder(encoder, model.cfg, camera_height)
    for tower in model.towers:
        frames = cast(FramePerception, tower)
        own = frames.frame_state_dict()
        if set(own) != set(encoder.state_dict):
            raise CheckpointError(f"encoder {encoder.path}: its weights do not match the "
                                  f"model's frame perception")
        frames.load_state_dict(encoder.state_dict, strict=False)
    model.freeze_frames()
