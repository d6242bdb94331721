"""The seeker: an expert whose every move can be inferred from what the agent sees.

The shortest-path oracle knows where the goal is from the first step, wherever it
is. A learner that imitates it must infer, from a panorama and a goal image, where a
goal is that may be behind a wall or across a room; when it cannot, the oracle's turns
towards the goal look random to it (left here, right in a look-alike state), their
mean is "no turn", and its mean action pushes on into whatever is ahead. The seeker
splits the oracle's knowledge along what a learner can perceive:

- **Searching** — until the goal is *in sight* (within ``sight`` metres, the straight
  segment to it on navigable cells), it explores like the goal-blind explorer, but
  deterministically: the most open direction (``open_fraction = 1``), the one nearest
  the heading on a tie, so every turn is a function of the depth panorama and
  odometry alone — the move the ``explore_action`` sensor reports
  (``EnvConfig.explore_action``), which a learner can therefore copy exactly.
- **Homing** — from the first step the goal is in sight until the episode ends, it
  follows the oracle (shortest path, kinematics-checked, around teammates).

Its homing moves are the oracle's where perception of the goal is easiest (near and
unoccluded); its searching moves cover ground the way the explorer does, which alone
succeeds on ~0.59 of easy episodes. The latch (once seen, keep homing) means a
learner with memory need not keep the goal in view.

Privileged like the oracle (``EnvConfig(privileged=True)``) and needs depth
(``EnvConfig(depth=True)``). Deterministic: no random draws. When the env executes actions
other than the seeker's (DAgger), pass them to :meth:`SeekerPolicy.executed` so the
odometry check ("the last drive fell short") compares against what was driven.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from collavn.errors import CollavnError
from collavn.metrics import SIGHT_DISTANCE
from collavn.policies.base import CommStats
from collavn.policies.explorer import ExplorerPolicy, ExplorerState
from collavn.policies.oracle import OraclePolicy, track_sighting
from collavn.scenes.scene import Scene
from collavn.simulation.kinematics import AgentParams

__all__ = ["SeekerPolicy", "SeekerState"]


class SeekerPolicy:
    """Explore (deterministically) until the goal is in sight, then follow the oracle.

    Args:
        scenes: The env's scenes (``obs["scene_index"]`` indexes them).
        sight: The goal is in sight within this Euclidean distance, metres, when the
            straight segment to it is navigable.
        params: The robot.
        seed: Kept for the policy interface (the seeker draws nothing at random).
    """

    def __init__(self, scenes: list[Scene], sight: float = SIGHT_DISTANCE,
                 params: AgentParams | None = None, seed: int = 0) -> None:
        if not sight > 0:
            raise CollavnError(f"the seeker's sight must be > 0 m, got {sight}")
        self.sight = float(sight)
        self.oracle = OraclePolicy(scenes, params)
        self.explorer = ExplorerPolicy(seed, params, open_fraction=1.0,
                                       deterministic=True)

    @property
    def scenes(self) -> list[Scene]:
        """The scenes the oracle plans in."""
        return self.oracle.scenes

    def initial_state(self, num_envs: int, num_agents: int) -> SeekerState:
        """Nobody has seen the goal yet; the explorer's memory is fresh."""
        return SeekerState(np.zeros((num_envs, num_agents), bool),
                           self.explorer.initial_state(num_envs, num_agents))

    def communication(self) -> CommStats:
        """The seeker never talks."""
        return CommStats()

    def act(self, obs: dict[str, np.ndarray], state: SeekerState
            ) -> tuple[np.ndarray, SeekerState]:
        """``(E, N, 2)`` actions: the oracle's for agents that have seen their goal."""
        if "world_pose" not in obs:
            raise KeyError("the seeker needs privileged observations: "
                           "EnvConfig(privileged=True)")
        actions, state.explore = self.explorer.act(obs, state.explore)
        pose, goal, active = obs["world_pose"], obs["goal_position"], obs["active"]
        state.seen = track_sighting(state.seen, obs, self.scenes, self.sight)
        for e, n in zip(*np.nonzero(active & state.seen), strict=True):
            scene = self.scenes[int(obs["scene_index"][e])]
            try:
                actions[e, n] = self.oracle.act_one(scene, pose[e], n, goal[e, n])
            except CollavnError:  # no path from here (pushed off the grid): explore
                pass
        self.executed(state, actions, active)
        return actions, state

    def executed(self, state: SeekerState, actions: np.ndarray, active: np.ndarray) -> None:
        """Record the ``(E, N, 2)`` actions the env was given (the odometry check's base)."""
        self.explorer.executed(state.explore, actions, active)


@dataclass
class SeekerState:
    """Per-agent memory of the seeker.

    Attributes:
        seen: ``(E, N)`` the goal has been in sight this episode (homing).
        explore: The explorer's memory (tie-break generators, the last drive).
    """

    seen: np.ndarray
    explore: ExplorerState
