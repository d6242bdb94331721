"""What the agents sense: panoramas, goal images, depth and ground-truth local maps.

Wraps one scene's renderer for batches of ``E`` envs × ``N`` agents. Every agent sees
the other agents of its own env (as robot bodies), never its own body, and never
the agents of other envs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from collavn.envs.config import EnvConfig
from collavn.envs.free_space import FREE_SPACE_RANGE, ExploreRule, free_runs
from collavn.rendering.cameras import CameraSpec
from collavn.rendering.renderer import Renderer
from collavn.scenes.scene import Scene
from collavn.simulation.kinematics import AgentParams

#: The rule of the ``explore_action`` sensor: the seeker's (only the most open direction).
EXPLORE_RULE = ExploreRule(open_fraction=1.0)


@dataclass(frozen=True)
class Views:
    """Panorama renders: ``rgb (E, N, 3, H, W)`` uint8, ``depth (E, N, H, W)`` float32."""

    rgb: np.ndarray
    depth: np.ndarray


class Sensors:
    """Cameras of the agents in one scene."""

    def __init__(self, scene: Scene, config: EnvConfig) -> None:
        self.scene, self.config = scene, config
        self.panorama = CameraSpec.panorama(config.panorama_width, config.panorama_height,
                                            mount_height=config.camera_height)
        self.goal = CameraSpec.pinhole(config.goal_size, config.goal_size,
                                       mount_height=config.camera_height)
        self.renderer = Renderer(scene, backend=config.backend, device=config.device,
                                 panorama=self.panorama, goal=self.goal,
                                 threads=config.render_threads)
        self._directions = self.panorama.ray_directions().astype(np.float64)

    def panoramas(self, poses: np.ndarray) -> Views:
        """Render every agent's panorama; ``poses (E, N, 3)``.

        Agent ``k``'s body is drawn (in agent ``k``'s colour) in the views of the
        other agents of the same env.
        """
        e, n, _ = poses.shape
        bodies = np.broadcast_to(poses[:, None, :, :2], (e, n, n, 2)).reshape(e * n, n, 2)
        own = np.tile(np.arange(n), e)
        out = self.renderer.render(poses.reshape(e * n, 3), "panorama", agents=bodies,
                                   exclude=own)
        h, w = self.panorama.height, self.panorama.width
        return Views(out.rgb.reshape(e, n, 3, h, w), out.depth.reshape(e, n, h, w))

    def free_space(self, depth: np.ndarray, radius: float) -> np.ndarray:
        """``(E, N, D)`` metres a body of ``radius`` can drive along each direction.

        The ``config.free_space`` directions, from the panoramas' depth ``(E, N, H, W)``.
        """
        return free_runs(depth, radius, self.config.camera_height,
                         np.deg2rad(self.panorama.fov_deg), horizon=FREE_SPACE_RANGE,
                         directions=self.config.free_space).astype(np.float32)

    def explore_action(self, depth: np.ndarray, bumped: np.ndarray,
                       params: AgentParams) -> np.ndarray:
        """``(E, N, 2)`` the explorer's deterministic move (:data:`EXPLORE_RULE`).

        From the panoramas' depth ``(E, N, H, W)`` and ``bumped (E, N)``: the last drive
        fell short of what its action should have driven.
        """
        e, n, _, w = depth.shape
        free = EXPLORE_RULE.free(depth.reshape(e * n, *depth.shape[2:]), params,
                                 self.config.camera_height,
                                 np.deg2rad(self.panorama.fov_deg))
        moves = EXPLORE_RULE.moves(free.reshape(e * n, w), bumped.reshape(e * n), params)
        return moves.reshape(e, n, 2).astype(np.float32)

    def goal_images(self, goal_poses: np.ndarray) -> np.ndarray:
        """Front views at goal poses ``(E, N, 3)`` (no robots in them): ``(E, N, 3, G, G)``."""
        e, n, _ = goal_poses.shape
        out = self.renderer.render(goal_poses.reshape(e * n, 3), "goal")
        g = self.goal.width
        return out.rgb.reshape(e, n, 3, g, g)

    def gt_maps(self, poses: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Egocentric ground-truth maps projected from the panorama depth.

        Channel 0: obstacle (a surface point between ``step_height`` and
        ``agent_height`` above the floor fell in the cell); channel 1: explored (any
        surface point fell in it, or it lies under the robot). Agent at the centre,
        heading up: row 0 is farthest ahead, column 0 farthest to the left; 10 cm cells.

        Args:
            poses: ``(E, N, 3)`` (only their count matters: maps are egocentric).
            depth: ``(E, N, H, W)`` distances along each pixel's ray (0 = no hit).

        Returns:
            ``(E, N, 2, M, M)`` float32 with ``M = config.gt_map_size``.
        """
        e, n = poses.shape[:2]
        want = (e, n, self.panorama.height, self.panorama.width)
        if tuple(depth.shape) != want:  # the kernel reads one ray per pixel: no broadcasting
            raise ValueError(f"gt_maps: depth {tuple(depth.shape)} does not fit {e}×{n} "
                             f"panoramas; expected {want}")
        m = self.config.gt_map_size
        nav = self.scene.nav.config
        res = nav.resolution
        maps = np.zeros((e * n, 2, m, m), np.float32)
        _project_kernel(np.ascontiguousarray(depth.reshape(e * n, -1)), self._directions,
                        float(self.panorama.mount_height), float(res), float(nav.step_height),
                        float(nav.agent_height), maps)
        body = int(np.ceil(nav.agent_radius / res))
        maps[:, 1, m // 2 - body:m // 2 + body, m // 2 - body:m // 2 + body] = 1.0
        return maps.reshape(e, n, 2, m, m)


@numba.njit(cache=True, nogil=True)
def _project_kernel(depth: np.ndarray, directions: np.ndarray, mount_height: float,
                    res: float, low: float, high: float,
                    maps: np.ndarray) -> None:  # pragma: no cover - compiled
    """Mark each pixel's hit of ``depth (B, P)`` in ``maps (B, 2, M, M)`` (see ``gt_maps``).

    A hit at ``d · direction`` (agent frame: forward, left, up) falls in row
    ``⌊M/2 − forward/res⌋``, column ``⌊M/2 − left/res⌋``; inside the map it is explored
    (channel 1), and an obstacle (channel 0) between ``low`` and ``high`` above the floor.
    """
    m = maps.shape[-1]
    for b in range(depth.shape[0]):
        for p in range(depth.shape[1]):
            d = np.float64(depth[b, p])
            if not (np.isfinite(d) and d > 0):
                continue
            row = int(np.floor(m / 2 - d * directions[p, 0] / res))
            col = int(np.floor(m / 2 - d * directions[p, 1] / res))
            if row < 0 or row >= m or col < 0 or col >= m:
                continue
            maps[b, 1, row, col] = 1.0
            height = d * directions[p, 2] + mount_height
            if height >= low and height <= high:
                maps[b, 0, row, col] = 1.0
