"""``collavn pick``: keep the snapshot of a run that scores best on training-scene episodes."""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Annotated

import tyro

from collavn.datasets.episode import Difficulty
from collavn.datasets.storage import Dataset
from collavn.errors import CollavnError
from collavn.evaluation.benchmark import EvalConfig, run_evaluation
from collavn.evaluation.compare import sr_interval
from collavn.policies.checkpoint import load_checkpoint, save_checkpoint
from collavn.training.checkpoint import run_snapshots


@dataclass(frozen=True)
class Pick:
    """Score a run's snapshots by the mean action on training-scene episodes; keep the best.

    A PPO policy's mean action moves by as much as ±0.1 SR between snapshots 61k agent-steps
    apart (docs/learning-log.md, 2026-12-07), so where a run stops is partly luck. This
    evaluates each ``--snapshot-every`` snapshot of ``RUN_DIR`` (the second half by default)
    on the episodes of ``--dataset``, which must come from the *train* split — episodes of
    the scenes the policy trained in (``collavn dataset generate --split train --scenes
    ...``), never the val or test episodes it will be reported on — pools SR over
    ``--difficulties``, and writes the best snapshot (ties: the later) to ``--out``.
    """

    run_dir: Annotated[Path, tyro.conf.Positional]
    """A run directory trained with ``--snapshot-every N``."""
    dataset: Path
    """An episode dataset with train-split episodes (other splits in it are ignored)."""
    out: Path
    """The picked checkpoint to write (atomically)."""
    from_steps: int | None = None
    """Snapshots from this many agent-steps on (default: the second half)."""
    difficulties: tuple[Difficulty, ...] = ("easy", "medium")
    """Difficulty bins scored (pooled over their episodes)."""
    num_envs: int = 8
    """Environments stepped together (a speed setting: results do not depend on it)."""
    seed: int = 0
    """Seeds the odometry noise per episode, as in ``evaluate``."""
    torch_threads: int = 0
    """torch / Numba threads; 0 = automatic, as in ``evaluate``."""
    progress: bool = True
    """Show a progress bar per evaluation."""

    def pick(self) -> tuple[Path, list[tuple[int, float, float, float, int]]]:
        """Evaluate every snapshot; write the best. Returns its source and the scores."""
        paths = run_snapshots(self.run_dir, self.from_steps)
        base = EvalConfig(policy=str(paths[0]), dataset=self.dataset, split="train",
                          num_envs=self.num_envs, seed=self.seed,
                          torch_threads=self.torch_threads, keep_trajectories=0,
                          progress=self.progress)
        dataset = Dataset.load(self.dataset, split="train")  # a broken file: its own error
        if len(dataset) == 0:
            raise CollavnError(
                f"{self.dataset} holds no train-split episodes: pick on episodes of the "
                f"training scenes (collavn dataset generate --split train --scenes ...), "
                f"not on the val or test episodes a policy is reported on")
        scores = []
        for path in paths:
            records = [r for d in self.difficulties
                       for r in run_evaluation(replace(base, policy=str(path), difficulty=d),
                                               dataset).records]
            if not records:
                raise CollavnError(f"no {'/'.join(self.difficulties)} train-split episodes "
                                   f"in {self.dataset}")
            sr, low, high, episodes = sr_interval(records)
            scores.append((int(load_checkpoint(path)["agent_steps"]), sr, low, high, episodes))
            print(f"{path.name}: SR {sr:.3f} [{low:.3f}, {high:.3f}] ({episodes} episodes)")
        best = max(range(len(paths)), key=lambda i: (scores[i][1], i))
        payload = {k: v for k, v in load_checkpoint(paths[best]).items() if k != "format"}
        payload["picked_from"] = [{"path": str(p), "agent_steps": s[0], "sr": s[1]}
                                  for p, s in zip(paths, scores, strict=True)]
        save_checkpoint(self.out, payload)
        return paths[best], scores

    def run(self) -> int:
        """Pick, write, and say which."""
        source, scores = self.pick()
        print(f"picked {source.name} (SR {max(s[1] for s in scores):.3f} on "
              f"{scores[0][4]} train-split episodes) → {self.out}")
        return 0
