"""Checkpoint files, and a trained model behind the policy interface.

A checkpoint file is one header line, ``collavn-checkpoint 3 sha256=<64 hex>``, then a
``torch.save`` payload holding the resolved training config (as a dict: ``{"method",
"preset", "env", "model", "ppo", "mapping", "imitation", "run"}``), the update counter,
the model and optimizer states. The checksum covers the payload and is verified on
every load: one flipped bit is refused as damage, never loaded. The file is written with
:func:`collavn.files.atomic_write`, so a kill at any moment leaves either the old or the
new checkpoint, never a torn one (a temporary file left by a hard kill is removed by
the next save).

Format history: 1 — flat config, agent scores as a softmax across agents (no teammate
message could pass η = ½ at N = 2); 2 — the config tree and the paper's per-pair
scores, a bare ``torch.save`` file; 3 — the same payload behind the checksum header.
Format-1 checkpoints are refused with that reason; format-2 files (no checksum) still
load.
"""

from __future__ import annotations

import copy
import io
from pathlib import Path
from typing import Any

import numpy as np
import torch

from collavn.configs import from_dict, to_dict
from collavn.errors import CheckpointError, ConfigError
from collavn.files import atomic_write, sha256_hex
from collavn.models.communication import Message, communication_counts
from collavn.models.config import ModelConfig, ReadoutConfig
from collavn.models.policy import ActorCritic, action_components, pick_component
from collavn.models.state import AgentState
from collavn.policies.adapter import env_overrides, episode_start, obs_to_torch, policy_keys
from collavn.policies.base import CommStats, EpisodeRandom

#: Bumped when the checkpoint layout or the meaning of its weights changes.
FORMAT_VERSION = 3
#: Formats :func:`load_checkpoint` reads (2: written before checksums, loaded unchecked).
READABLE_FORMATS = (2, 3)
#: First word of a checkpoint file's header line.
MAGIC = b"collavn-checkpoint"

#: Envs per forward pass of :class:`CheckpointPolicy` (a fixed batch size: see there).
BLOCK_ENVS = 8

#: Why older formats are refused.
_OLD_FORMATS = {1: "written before the configuration tree and the per-pair communication "
                   "scores (its communication semantics changed: a softmax across agents "
                   "let no teammate message through at N = 2); train it again"}


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` (plus the format version) to ``path`` atomically, checksummed.

    Raises:
        CheckpointError: the file cannot be written (disk full, no permission); the
            previous checkpoint at ``path``, if any, is left as it was.
    """
    buf = io.BytesIO()
    torch.save({"format": FORMAT_VERSION, **payload}, buf)
    body = buf.getvalue()
    header = MAGIC + f" {FORMAT_VERSION} sha256={sha256_hex(body)}\n".encode()
    try:
        return atomic_write(path, header + body, clean_stale=True)
    except OSError as e:
        raise CheckpointError(f"cannot write checkpoint {path}: {e.strerror or e}; the "
                              f"previous checkpoint there (if any) is unchanged") from e


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu"
                    ) -> dict[str, Any]:
    """Read and verify a checkpoint.

    Raises:
        CheckpointError: missing, unreadable, damaged (checksum mismatch), an old or
            foreign format, or weights holding NaN or inf.
    """
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"no checkpoint at {path}")
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise CheckpointError(f"cannot read checkpoint {path}: {e.strerror or e}") from e
    body, checked = _verified_body(raw, path)
    try:
        payload = torch.load(io.BytesIO(body), map_location=map_location, weights_only=False)
    except Exception as e:  # torch raises many kinds on a corrupt file
        raise CheckpointError(f"cannot read checkpoint {path}: {e}") from e
    version = payload.get("format") if isinstance(payload, dict) else None
    if version in _OLD_FORMATS:
        raise CheckpointError(f"checkpoint {path} has format {version}: "
                              f"{_OLD_FORMATS[version]}")
    if version not in READABLE_FORMATS or (version == FORMAT_VERSION) != checked:
        raise CheckpointError(f"{path} is not a collavn training checkpoint "
                              f"(format {FORMAT_VERSION})")
    _check_finite(payload, path)
    _add_later_fields(payload)
    return payload


#: Config fields added after format 3 (dotted paths), with the value meaning "as before":
#: no readout (or the pooled one), every PPO epoch, the map encoder's first widths, the
#: value loss's gradient reaching the messages, one learning rate for all, one Gaussian.
LATER_FIELDS: dict[str, Any] = {
    "model.readout": to_dict(ReadoutConfig(enabled=False)),
    "model.readout.ring": False,
    "model.free_space_input": 0,
    "model.map.encoder_channels": [32, 64, 64],
    "ppo.target_kl": 0.0,
    "model.comm.critic_gradient": True,
    "ppo.comm_lr_scale": 1.0,
    "model.action_modes": 1,
    "model.explore_prior": False,
    "model.frame_depth": False,
    "model.goal_belief": 0,
    "imitation.belief_coef": 1.0,
    "env.success_reward": 0.0,
    "env.collision_penalty": 0.05,
    "imitation.lr_decay": False,
    "imitation.homing_weight": 1.0,
    "run.train_scenes": 25,
    "ppo.bc_target": "expert",
    "ppo.bc_steps": "all",
    "run.resume_from": "",
    "ppo.message_floor": 0.0,
    "ppo.message_floor_coef": 1.0,
    "run.snapshot_every": 0,
    "ppo.end_std": 0.0,
    "ppo.bc_blocked_window": 3,
}


def _add_later_fields(payload: dict[str, Any]) -> None:
    """Fill config fields a checkpoint predates with the value its run behaved by.

    A checkpoint written before the perception readout existed had none, so it loads
    with ``model.readout.enabled = False`` (the strict config reader refuses missing
    keys); one from before ``ppo.target_kl`` ran every epoch (0).
    """
    config = payload.get("config")
    for path, value in LATER_FIELDS.items():
        *parents, leaf = path.split(".")
        node = config
        for key in parents:
            node = node.get(key) if isinstance(node, dict) else None
        if isinstance(node, dict) and leaf not in node:
            node[leaf] = copy.deepcopy(value)


def _verified_body(raw: bytes, path: Path) -> tuple[bytes, bool]:
    """The payload bytes of a file and whether a checksum verified them (format 3)."""
    if not raw.startswith(MAGIC + b" "):
        return raw, False
    end = raw.find(b"\n")
    words = raw[:end].split() if end > 0 else []
    body = raw[end + 1:]
    if len(words) != 3 or not words[2].startswith(b"sha256="):
        raise CheckpointError(f"checkpoint {path} is damaged: its header is unreadable")
    if sha256_hex(body) != words[2][len(b"sha256="):].decode(errors="replace"):
        raise CheckpointError(f"checkpoint {path} is damaged: its content does not match "
                              f"its sha256 checksum (bit rot or a torn copy); restore it "
                              f"from a copy or train again")
    return body, True


def _check_finite(payload: dict[str, Any], path: Path) -> None:
    """Refuse model weights holding NaN or inf (a diverged run)."""
    model = payload.get("model")
    if not isinstance(model, dict):
        return
    for name, value in model.items():
        if (isinstance(value, torch.Tensor) and value.is_floating_point()
                and not bool(torch.isfinite(value).all())):
            raise CheckpointError(f"checkpoint {path}: weight {name} holds NaN or inf "
                                  f"(the run diverged?); use an earlier checkpoint")


def tally(message: Message, active: torch.Tensor) -> CommStats:
    """One communication round of ``(E, N)`` agents as a :class:`CommStats`."""
    counts = communication_counts(message, active)
    return CommStats(int(active.sum()), int(counts.received.sum()), int(counts.when.sum()),
                     float(counts.bytes.sum()))


def checkpoint_model_config(payload: dict[str, Any], path: str | Path) -> ModelConfig:
    """The :class:`ModelConfig` a checkpoint's weights belong to."""
    try:
        return from_dict(ModelConfig, payload["config"]["model"], "model.")
    except (ConfigError, KeyError, TypeError) as e:
        raise CheckpointError(f"checkpoint {path} has an unreadable model config: {e}") from e


class CheckpointPolicy:
    """A trained :class:`ActorCritic` as a policy.

    Numpy observations go to torch on the model's device; ``episode_start`` comes from
    ``obs["step"] == 0``; actions are the policy mean clipped to [-1, 1], or with
    ``stochastic`` samples of the Gaussian (seeded per episode by ``seed`` and
    ``obs["episode_seed"]``). Works for any number of agents (Ad-hoCoop; ``il`` copies).

    The model runs on fixed-size blocks of ``block_envs`` envs (the last one padded
    with copies of its first env, marked inactive): a batch of another size rounds
    floating point differently, while within a block of fixed size an env's result
    depends neither on its position nor on the other envs (tested for the ``cpu``
    preset's sizes), so ``num_envs`` does not change the results. Some small layer
    shapes make the BLAS kernels round a row by its position in the batch (the tests'
    tiny model with communication: known, marked xfail); there an episode's digits
    depend on its slot. ``block_envs = 1`` runs one env at a time (slower, exact).
    """

    def __init__(self, model: ActorCritic, stochastic: bool = False, seed: int = 0,
                 block_envs: int = BLOCK_ENVS) -> None:
        if block_envs < 1:
            raise ValueError(f"block_envs must be ≥ 1, got {block_envs}")
        self.block_envs = block_envs
        self.model = model.eval()
        self.keys = policy_keys(model.cfg)
        self.stochastic = stochastic
        self.random = EpisodeRandom(seed)
        self.comm = CommStats()

    def initial_state(self, num_envs: int, num_agents: int) -> AgentState:
        """Zero recurrent state."""
        return self.model.initial_state(num_envs, num_agents)

    def act(self, obs: dict[str, np.ndarray], state: AgentState
            ) -> tuple[np.ndarray, AgentState]:
        """Actions ``(E, N, 2)`` (the mean, or a sample if ``stochastic``), next state.

        Samples are ``mean + std · ε`` with ``ε`` drawn per episode
        (:class:`~collavn.policies.base.EpisodeRandom`), of a mixture's component picked
        by a uniform draw from the same generator (none for one Gaussian); torch's random
        state is not used.
        """
        device = self.model.device
        obs_t, start = obs_to_torch(obs, self.keys, device), episode_start(obs, device)
        parts: list[tuple[torch.Tensor, ...]] = []
        states = []
        with torch.no_grad():
            size = self.block_envs
            for lo in range(0, start.shape[0], size):  # see the class docstring
                real = slice(lo, min(lo + size, start.shape[0]))
                k = real.stop - lo
                block = {key: _padded(v[real], size) for key, v in obs_t.items()}
                block["active"][k:] = False
                part = state.select_envs(real)
                step = self.model(block, AgentState.cat([part] + [part.select_envs(
                    slice(0, 1))] * (size - k)), _padded(start[real], size))
                parts.append(tuple(x[:k] for x in action_components(step.dist)))
                states.append(step.state.select_envs(slice(0, k)))
                self.comm.add(tally(step.message, block["active"]))
        loc, scale, logits = (torch.cat(x) for x in zip(*parts, strict=True))
        n = obs["active"].shape[1]
        u = (torch.as_tensor(self.random.uniform(obs, 0.0, 1.0, (n,)), dtype=loc.dtype,
                             device=device)
             if self.stochastic and logits.shape[-1] > 1 else None)
        raw, std = pick_component(loc, scale, logits, u)
        if self.stochastic:
            eps = torch.as_tensor(self.random.normal(obs, (n, raw.shape[-1])),
                                  dtype=raw.dtype, device=device)
            raw = raw + std * eps
        return raw.clamp(-1.0, 1.0).cpu().numpy().astype(np.float64), AgentState.cat(states)

    def communication(self) -> CommStats:
        """Communication of every call to :meth:`act` so far."""
        return self.comm


def _padded(x: torch.Tensor, size: int) -> torch.Tensor:
    """``x (k, ...)`` with its first env repeated to ``size`` envs."""
    return torch.cat([x, x[:1].expand(size - len(x), *x.shape[1:])])


def refuse_silent(model_cfg: ModelConfig, path: str | Path) -> None:
    """``--mute`` needs messages to cut: refuse a checkpoint whose model sends none."""
    if model_cfg.comm.variant == "none":
        raise CheckpointError(f"--mute: checkpoint {path} has no communication "
                              f"(its comm variant is 'none')")
    if not model_cfg.comm.listen:
        raise CheckpointError(f"--mute: checkpoint {path} was trained with "
                              f"--model.comm.no-listen: its agents hear no teammate already")
    if not model_cfg.comm.actor_hears:
        raise CheckpointError(f"--mute: checkpoint {path} was trained with "
                              f"--model.comm.no-actor-hears: its actor hears no teammate "
                              f"already (only its critic did, in training)")


def load_policy(path: str | Path, device: str = "cpu", stochastic: bool = False,
                seed: int = 0, mute: bool = False) -> tuple[CheckpointPolicy, dict[str, Any]]:
    """A checkpoint as an evaluation policy, plus the env settings it needs.

    ``mute`` cuts the links between teammates (an ablation; see
    :attr:`ActorCritic.listen`). A policy trained with ``CommConfig.actor_hears`` off
    acts on its own memory alone: its links are cut too (its critic, which heard its
    teammates in training, plays no part in acting).

    Returns:
        The policy and ``EnvConfig`` overrides (image sizes, depth).
    """
    payload = load_checkpoint(path, map_location=device)
    model_cfg = checkpoint_model_config(payload, path)
    if mute:
        refuse_silent(model_cfg, path)
    model = ActorCritic(model_cfg, device=device)  # listens as trained (CommConfig.listen)
    if mute or not model_cfg.comm.actor_hears:
        model.listen = False
    try:
        model.load_state_dict(payload["model"])
    except (RuntimeError, KeyError) as e:
        detail = "; ".join(line.strip() for line in str(e).splitlines()[1:3])
        raise CheckpointError(f"checkpoint {path}: its weights do not fit its model "
                              f"config ({detail or e})") from e
    return CheckpointPolicy(model, stochastic, seed), env_overrides(model_cfg)
