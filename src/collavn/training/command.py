"""``collavn train``: pick a method and a preset, override what you need, train.

Example::

    collavn train --method ours --task commongoal --agents 2 --preset cpu --out runs/ours
    torchrun --nproc-per-node 2 -m collavn.cli train --method no-com --preset cpu --out runs/x

Any field left at ``None`` takes the preset's value; the resolved configuration is
written to ``OUT/config.json`` and into every checkpoint.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from collavn.training.config import Method, Preset, TrainConfig


@dataclass
class Train:
    """Train a navigation agent (decentralized PPO or imitation) and write checkpoints."""

    method: Method = "ours"
    """``ours`` (memory communication), ``no-mem`` (handshake), ``no-com`` (IPPO), ``il``."""
    task: str = "commongoal"
    """``commongoal``, ``specificgoal`` or ``adhocoop``."""
    agents: int = 2
    """Agents per env during training."""
    preset: Preset = "cpu"
    """``paper`` (ResNet18, 512×128, 25 envs, paper hyper-parameters) or ``cpu``."""
    out: str = "runs/train"
    """Run directory (config.json, checkpoint.pt, TensorBoard events)."""
    resume: bool = False
    """Continue from ``OUT/checkpoint.pt`` (refused if it was made by another config)."""
    total_steps: int = 10_000_000
    """Stop after this many agent-steps."""
    time_budget_minutes: float = 0.0
    """Stop with a checkpoint after this wall-clock time (0 = no limit)."""
    seed: int = 0
    """Base seed (process r adds 1000·r)."""
    device: str = "cpu"
    """Torch device (``cpu`` or ``cuda``)."""
    difficulty: str | None = None
    """Training episode difficulty (easy, medium, hard, mixed)."""
    num_envs: int | None = None
    """Envs per process."""
    rollout_steps: int | None = None
    """Env steps per rollout."""
    lr: float | None = None
    """Learning rate (PPO, or imitation for ``il``)."""
    update_epochs: int | None = None
    """PPO epochs per rollout."""
    num_minibatches: int | None = None
    """PPO mini-batches per epoch."""
    critic_warmup: int | None = None
    """PPO: the first this-many updates train only the critic (use with --init-from)."""
    panorama_width: int | None = None
    """Panorama width."""
    panorama_height: int | None = None
    """Panorama height."""
    goal_size: int | None = None
    """Goal image side."""
    render_threads: int | None = None
    """Renderer threads per process."""
    torch_threads: int | None = None
    """Torch threads per process (0 = torch's default)."""
    dagger: bool | None = None
    """``il`` only: DAgger (True) or plain behaviour cloning (False)."""
    map_updates: int | None = None
    """Map updates each time the map trains."""
    checkpoint_interval: int | None = None
    """Updates between checkpoints (sync points)."""
    init_from: str = ""
    """Start from this checkpoint's model weights (e.g. an ``il`` run to fine-tune with
    PPO); the model config must match."""
    progress: bool = True
    """Show a progress bar."""

    def config(self) -> TrainConfig:
        """The resolved configuration: preset, then the given overrides."""
        top: dict[str, Any] = dict(
            method=self.method, task=self.task, agents=self.agents, out=self.out,
            total_steps=self.total_steps, time_budget_minutes=self.time_budget_minutes,
            seed=self.seed, device=self.device, progress=self.progress,
            init_from=self.init_from)
        for name in ("difficulty", "num_envs", "panorama_width", "panorama_height",
                     "goal_size", "render_threads", "torch_threads", "checkpoint_interval"):
            if getattr(self, name) is not None:
                top[name] = getattr(self, name)
        cfg = TrainConfig.preset_config(self.preset, **top)
        ppo = {k: getattr(self, k) for k in ("rollout_steps", "update_epochs",
                                              "num_minibatches", "critic_warmup")
               if getattr(self, k) is not None}
        if self.lr is not None and self.method != "il":
            ppo["lr"] = self.lr
        imitation: dict[str, Any] = {} if self.dagger is None else {"dagger": self.dagger}
        if self.lr is not None and self.method == "il":
            imitation["lr"] = self.lr
        mapping: dict[str, Any] = ({} if self.map_updates is None
                                   else {"updates": self.map_updates})
        return replace(cfg, ppo=replace(cfg.ppo, **ppo),
                       imitation=replace(cfg.imitation, **imitation),
                       mapping=replace(cfg.mapping, **mapping)).resolved()

    def run(self) -> int:
        """Train; print where the checkpoint went."""
        from collavn.training.trainer import train

        result = train(self.config(), resume=self.resume)
        if result.checkpoint is not None:
            sr = result.last.get("episode/success_rate", float("nan"))
            print(f"{result.iterations} updates, {result.agent_steps} agent-steps, "
                  f"training SR {sr:.3f}; checkpoint {result.checkpoint}")
        return 0
