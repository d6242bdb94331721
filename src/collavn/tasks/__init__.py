"""The three task settings: goals, reward, success — pure functions over batches.

- *CommonGoal*: N agents, one shared goal image.
- *SpecificGoal*: N agents, N pairwise distinct goal images.
- *Ad-hoCoop*: a shared goal; trained with N agents, evaluated with N' ≠ N. The
  rules are CommonGoal's; only the number of agents at evaluation differs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from collavn.errors import CollavnError
from collavn.simulation.world import World


@dataclass(frozen=True)
class TaskSpec:
    """Rules of one task setting (DESIGN.md numbers by default).

    Attributes:
        name: ``commongoal``, ``specificgoal`` or ``adhocoop``.
        shared_goal: All agents share one goal (CommonGoal, Ad-hoCoop).
        success_distance: An agent succeeds at geodesic distance ≤ this (metres).
        max_steps: Episode length ``T``; agents still running then are truncated.
        progress_weight: Reward per metre of geodesic progress.
        collision_penalty: Subtracted on every step with a collision.
        success_reward: Added on the step an agent reaches its goal (0 = the paper's
            reward, which pays only for progress).

    The discount γ is the learner's (``PPOConfig.gamma``), not the task's.
    """

    name: str
    shared_goal: bool
    success_distance: float = 1.0
    max_steps: int = 80
    progress_weight: float = 1.0
    collision_penalty: float = 0.05
    success_reward: float = 0.0


#: A task setting's name (the keys of :data:`TASKS`).
TaskName = Literal["commongoal", "specificgoal", "adhocoop"]

#: The task settings by name (keys: :data:`TaskName`'s values).
TASKS: dict[str, TaskSpec] = {
    "commongoal": TaskSpec("commongoal", shared_goal=True),
    "specificgoal": TaskSpec("specificgoal", shared_goal=False),
    "adhocoop": TaskSpec("adhocoop", shared_goal=True),
}


def get_task(name: str) -> TaskSpec:
    """The :class:`TaskSpec` called ``name`` (case-insensitive, ``-``/``_`` ignored)."""
    key = name.lower().replace("-", "").replace("_", "")
    if key not in TASKS:
        raise CollavnError(f"unknown task {name!r}; expected one of {', '.join(TASKS)}")
    return TASKS[key]


def step_reward(prev_distance: np.ndarray, distance: np.ndarray, collided: np.ndarray,
                running: np.ndarray, task: TaskSpec) -> np.ndarray:
    """Per-agent reward ``w·(d_{t-1} − d_t) − c·[collision] + s·[arrived]``.

    ``s`` is ``TaskSpec.success_reward`` (0 in the paper), paid on the step a running
    agent comes within the success radius; finished agents get zero.
    All arrays ``(E, N)``; distances are geodesic metres to each agent's own goal.
    """
    r = task.progress_weight * (prev_distance - distance)
    r = r - task.collision_penalty * collided.astype(np.float64)
    r = r + task.success_reward * succeeded(distance, task)
    return np.where(running, r, 0.0)


def succeeded(distance: np.ndarray, task: TaskSpec) -> np.ndarray:
    """``(E, N)`` bool: geodesic distance to the goal within the success radius."""
    return distance <= task.success_distance


@dataclass(frozen=True)
class StepOutcome:
    """What one step did, per agent: all arrays ``(E, N)``.

    ``terminated``/``truncated`` are True only on the step where the agent finished
    (Gymnasium semantics: terminated = reached the goal, truncated = hit ``T``).
    """

    reward: np.ndarray
    collided: np.ndarray
    terminated: np.ndarray
    truncated: np.ndarray

    @property
    def any_finished(self) -> np.ndarray:
        """``(E,)`` bool: some agent of the env finished on this step."""
        return (self.terminated | self.truncated).any(axis=1)


def step_world(world: World, action: np.ndarray, task: TaskSpec) -> StepOutcome:
    """Drive ``world`` one step with ``(E, N, 2)`` actions and apply ``task``'s rules."""
    motion = world.step(action)
    reward = step_reward(motion.prev_distance, world.distance, motion.collided,
                         motion.moving, task)
    terminated = motion.moving & succeeded(world.distance, task)
    truncated = motion.moving & ~terminated & (world.steps >= task.max_steps)
    world.finish(terminated, truncated)
    return StepOutcome(reward, motion.collided, terminated, truncated)
