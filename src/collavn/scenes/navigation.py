"""Where a robot can drive: traversability grid, components and geodesic distances.

Grid convention: cell ``(r, c)`` covers ``x ∈ origin_x + [c, c+1)·res`` and
``y ∈ origin_y + [r, r+1)·res`` — rows follow +y, columns follow +x. Images of the
grid are flipped vertically for display so that +y points up.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numba
import numpy as np
import skfmm
from scipy import ndimage

from collavn.errors import SceneError
from collavn.scenes.limits import SizeLimits
from collavn.scenes.traversability import floor_cells, obstacle_cells

#: The robot's body radius in metres (LoCoBot, 0.36 m wide): navigation, kinematics and
#: the bodies other agents see all use this one value.
ROBOT_RADIUS = 0.18


@dataclass(frozen=True)
class NavConfig:
    """How traversability is derived from geometry.

    Attributes:
        resolution: Grid cell size in metres (the paper's traversability map: 0.10 m).
        agent_radius: Robot body radius in metres (:data:`ROBOT_RADIUS`); free space is
            eroded by it, so a navigable cell is a valid position for the robot centre.
        agent_height: Geometry between ``step_height`` and this height above the
            floor blocks the robot (its camera mast reaches 0.9 m).
        step_height: Bumps lower than this (rugs, thresholds) do not block.
        sample_step: Spacing in metres of the points sampled on triangles to find
            obstacles; smaller than a table leg so thin legs are not missed.
    """

    resolution: float = 0.10
    agent_radius: float = ROBOT_RADIUS
    agent_height: float = 1.0
    step_height: float = 0.05
    sample_step: float = 0.03


@dataclass(frozen=True, eq=False)
class NavGrid:
    """Traversability and connectivity of one floor.

    Attributes:
        config: The parameters it was computed with.
        origin: ``(2,)`` world (x, y) of the grid's lower-left corner.
        floor: ``(H, W)`` bool, a floor surface is present.
        free: ``(H, W)`` bool, floor present and nothing in the robot's height band.
        navigable: ``(H, W)`` bool, free and at least ``agent_radius`` from any
            non-free cell: valid positions of the robot centre.
        components: ``(H, W)`` int32 connected-component label of navigable cells
            (8-connectivity), 0 elsewhere; labels sorted by size, 1 = largest.
        clearance: ``(H, W)`` float32 metres from the cell centre to the nearest
            non-free cell centre.
    """

    config: NavConfig
    origin: np.ndarray
    floor: np.ndarray
    free: np.ndarray
    navigable: np.ndarray
    components: np.ndarray
    clearance: np.ndarray

    # ------------------------------------------------------------ construction
    @classmethod
    def from_triangles(cls, triangles: np.ndarray, floor_z: float, config: NavConfig,
                       name: str = "scene", limits: SizeLimits | None = None) -> NavGrid:
        """Compute the grid from ``(F, 3, 3)`` triangles for the floor at ``floor_z``.

        Raises:
            SceneError: a grid larger than ``limits`` allows (checked before it is
                allocated), no floor at ``floor_z``, or no navigable area.
        """
        res = config.resolution
        lo = triangles.reshape(-1, 3).min(axis=0)
        hi = triangles.reshape(-1, 3).max(axis=0)
        origin = np.floor(lo[:2] / res) * res - res
        shape = (int(np.ceil((hi[1] - origin[1]) / res)) + 2,
                 int(np.ceil((hi[0] - origin[0]) / res)) + 2)
        (limits or SizeLimits()).check_grid(shape, res, name)
        floor = floor_cells(triangles, floor_z, origin, shape, config)
        if not floor.any():
            raise SceneError(f"{name}: no floor surface at height z={floor_z:.2f} m")
        blocked = obstacle_cells(triangles, floor_z, origin, shape, config)
        free = floor & ~blocked
        return cls.from_free(config, origin, floor, free, name=name)

    @classmethod
    def from_free(cls, config: NavConfig, origin: np.ndarray, floor: np.ndarray,
                  free: np.ndarray, name: str = "scene") -> NavGrid:
        """Erode ``free`` by the robot radius and label connected components."""
        res = config.resolution
        clearance = (ndimage.distance_transform_edt(free) * res).astype(np.float32)
        navigable = clearance - 0.5 * res >= config.agent_radius - 1e-6
        if not navigable.any():
            raise SceneError(
                f"{name}: no navigable area: no floor region is wide enough for a robot "
                f"of radius {config.agent_radius} m")
        labels, count = ndimage.label(navigable, structure=np.ones((3, 3), dtype=bool))
        sizes = np.bincount(labels.ravel(), minlength=count + 1)[1:]
        order = np.argsort(-sizes, kind="stable")
        relabel = np.zeros(count + 1, dtype=np.int32)
        relabel[order + 1] = np.arange(1, count + 1, dtype=np.int32)
        return cls(config=config, origin=np.asarray(origin, dtype=np.float64),
                   floor=floor, free=free, navigable=navigable,
                   components=relabel[labels], clearance=clearance)

    def to_arrays(self) -> dict[str, np.ndarray]:
        """Arrays for saving; inverse of :meth:`from_arrays`."""
        cfg = asdict(self.config)
        return {"nav_origin": self.origin, "nav_floor": self.floor, "nav_free": self.free,
                "nav_config": np.array([cfg[k] for k in sorted(cfg)], dtype=np.float64)}

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray]) -> NavGrid:
        """Rebuild from :meth:`to_arrays` output (components are recomputed: cheap)."""
        keys = sorted(asdict(NavConfig()))
        config = NavConfig(**{k: float(v) for k, v in zip(keys, arrays["nav_config"],
                                                           strict=True)})
        return cls.from_free(config, arrays["nav_origin"], arrays["nav_floor"],
                             arrays["nav_free"])

    # ----------------------------------------------------------------- queries
    @property
    def shape(self) -> tuple[int, int]:
        """``(H, W)`` of the grid."""
        h, w = self.navigable.shape
        return int(h), int(w)

    @property
    def resolution(self) -> float:
        """Cell size in metres."""
        return self.config.resolution

    def to_cell(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Rows and columns of the cells containing ``(..., 2)`` points (unclipped)."""
        xy = np.asarray(xy, dtype=np.float64)
        c = np.floor((xy[..., 0] - self.origin[0]) / self.resolution).astype(np.int64)
        r = np.floor((xy[..., 1] - self.origin[1]) / self.resolution).astype(np.int64)
        return r, c

    def cell_centers(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """World ``(..., 2)`` centres of the given cells."""
        x = self.origin[0] + (np.asarray(cols) + 0.5) * self.resolution
        y = self.origin[1] + (np.asarray(rows) + 0.5) * self.resolution
        return np.stack([x, y], axis=-1)

    def lookup(self, grid: np.ndarray, xy: np.ndarray, outside: float | bool = 0) -> np.ndarray:
        """Value of ``grid`` at the cells containing ``(..., 2)`` points."""
        r, c = self.to_cell(xy)
        h, w = self.shape
        inside = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        out = np.full(r.shape, outside, dtype=grid.dtype)
        out[inside] = grid[r[inside], c[inside]]
        return out

    def is_navigable(self, xy: np.ndarray) -> np.ndarray:
        """Whether the robot centre may stand at each of the ``(..., 2)`` points."""
        return self.lookup(self.navigable, xy, outside=False)

    def component_at(self, xy: np.ndarray) -> np.ndarray:
        """Component label at each point (0 = not navigable)."""
        return self.lookup(self.components, xy, outside=0)

    def component_sizes(self) -> np.ndarray:
        """Area in m² of each component, index 0 = component 1 (the largest)."""
        counts = np.bincount(self.components.ravel())[1:]
        return counts * self.resolution**2

    def geodesic_field(self, goal: np.ndarray,
                       blocked: np.ndarray | None = None) -> GeodesicField:
        """Fast-marching distance field to ``goal`` within the goal's component.

        Args:
            goal: ``(2,)`` world point on navigable floor.
            blocked: Optional ``(H, W)`` bool of extra cells to avoid (e.g. other
                robots); ignored where it would cover the goal itself.
        """
        goal = np.asarray(goal, dtype=np.float64).reshape(2)
        label = int(self.component_at(goal))
        if label == 0:
            raise SceneError(f"goal ({goal[0]:.2f}, {goal[1]:.2f}) is not on navigable floor")
        region = self.components == label
        if blocked is not None and not self.lookup(blocked, goal, outside=False):
            region = region & ~blocked
        return GeodesicField(self, goal, _fast_march(self, goal, region))

    def discs(self, centres: np.ndarray, radius: float) -> np.ndarray:
        """``(H, W)`` bool: cells whose centre lies within ``radius`` of any centre."""
        out = np.zeros(self.shape, dtype=bool)
        res = self.resolution
        k = int(np.ceil(radius / res)) + 1
        for centre in np.asarray(centres, dtype=np.float64).reshape(-1, 2):
            r0, c0 = (int(v) for v in self.to_cell(centre))
            rows = np.arange(max(r0 - k, 0), min(r0 + k + 1, self.shape[0]))
            cols = np.arange(max(c0 - k, 0), min(c0 + k + 1, self.shape[1]))
            rr, cc = np.meshgrid(rows, cols, indexing="ij")
            near = np.linalg.norm(self.cell_centers(rr, cc) - centre, axis=-1) <= radius
            out[rr[near], cc[near]] = True
        return out


@numba.njit(cache=True, nogil=True)
def _distance_kernel(xy: np.ndarray, grid: np.ndarray, ox: float, oy: float, res: float,
                     gx: float, gy: float) -> np.ndarray:  # pragma: no cover - compiled
    h, w = grid.shape
    out = np.empty(xy.shape[0])
    for k in range(xy.shape[0]):
        x, y = xy[k, 0], xy[k, 1]
        if not (math.isfinite(x) and math.isfinite(y)):
            out[k] = abs(x) + abs(y)  # nan stays nan, ±inf gives inf (as the array form)
            continue
        c0 = np.int64(math.floor((x - ox) / res - 0.5))
        r0 = np.int64(math.floor((y - oy) / res - 0.5))
        best = np.inf
        for dr in range(2):
            for dc in range(2):
                r, c = r0 + dr, c0 + dc
                d = grid[r, c] if 0 <= r < h and 0 <= c < w else np.inf
                dx = x - (ox + (c + 0.5) * res)
                dy = y - (oy + (r + 0.5) * res)
                best = min(best, d + math.sqrt(dx * dx + dy * dy))
        dx, dy = x - gx, y - gy
        near = math.sqrt(dx * dx + dy * dy)
        if near <= res:
            best = min(best, near)
        out[k] = max(best, near)
    return out


class GeodesicField:
    """Geodesic distance from every navigable cell to one goal point.

    ``grid`` is ``(H, W)`` float64 metres from each cell centre to the goal through
    navigable space; ``inf`` outside the goal's component.
    """

    def __init__(self, nav: NavGrid, goal: np.ndarray, grid: np.ndarray) -> None:
        self.nav = nav
        self.goal = goal
        self.grid = grid

    def distance(self, xy: np.ndarray) -> np.ndarray:
        """Geodesic distance from ``(..., 2)`` points to the goal (``inf`` if cut off).

        The value is the minimum over the 2×2 surrounding cell centres of (cell
        distance + straight-line distance to that centre), exact within one cell.
        Within one cell of the goal the straight line is the geodesic; everywhere the
        geodesic is at least the straight line (fast marching can dip below it). A
        compiled kernel (the simulator asks every step): the same float64 operations in
        the same order as the array form it replaced, tested bit-equal.
        """
        xy = np.asarray(xy, dtype=np.float64)
        if xy.ndim == 0 or xy.shape[-1] != 2:
            raise ValueError(f"distance takes (..., 2) points, got shape {xy.shape}")
        flat = np.ascontiguousarray(xy.reshape(-1, 2))
        out = _distance_kernel(flat, self.grid, float(self.nav.origin[0]),
                               float(self.nav.origin[1]), float(self.nav.resolution),
                               float(self.goal[0]), float(self.goal[1]))
        return out.reshape(xy.shape[:-1])

    def path_from(self, start: np.ndarray) -> np.ndarray:
        """``(K, 2)`` waypoints from ``start`` to the goal by steepest descent.

        Raises:
            SceneError: if ``start`` cannot reach the goal.
        """
        r, c = (int(v) for v in self.nav.to_cell(start))
        h, w = self.nav.shape
        padded = np.pad(self.grid, 1, constant_values=np.inf)
        if 0 <= r < h and 0 <= c < w and not np.isfinite(self.grid[r, c]):
            # The start's own cell is cut off (e.g. blocked by a robot): begin at the
            # best neighbouring cell instead.
            k = int(np.argmin(padded[r:r + 3, c:c + 3]))
            r, c = r + k // 3 - 1, c + k % 3 - 1
        if not (0 <= r < h and 0 <= c < w) or not np.isfinite(self.grid[r, c]):
            raise SceneError(f"start ({start[0]:.2f}, {start[1]:.2f}) cannot reach the goal")
        cells = [(r, c)]
        for _ in range(h * w):
            window = padded[r:r + 3, c:c + 3]
            k = int(np.argmin(window))
            nr, nc = r + k // 3 - 1, c + k % 3 - 1
            if window.flat[k] >= self.grid[r, c]:
                break
            r, c = nr, nc
            cells.append((r, c))
        rows, cols = np.array(cells).T
        points = self.nav.cell_centers(rows, cols)
        return np.concatenate([np.asarray(start, dtype=np.float64).reshape(1, 2),
                               points[1:], self.goal.reshape(1, 2)])


# ----------------------------------------------------------------- internals
def _fast_march(nav: NavGrid, goal: np.ndarray, region: np.ndarray) -> np.ndarray:
    res = nav.resolution
    rows, cols = np.mgrid[0:nav.shape[0], 0:nav.shape[1]]
    centres = nav.cell_centers(rows, cols)
    radius = 0.75 * res  # zero level set: a small circle around the goal
    phi = np.linalg.norm(centres - goal, axis=-1) - radius
    out = np.full(nav.shape, np.inf)
    # Fast marching steps between edge neighbours only, so the goal reaches exactly the
    # 4-connected piece of ``region`` around its cell (other robots' discs can cut a
    # component into pieces, or wall the goal in). Everything else stays ``inf``.
    labels, _ = ndimage.label(region)
    r, c = (int(v) for v in nav.to_cell(goal))
    piece = (labels == labels[r, c]) & region
    if not (phi[piece] > 0).any():
        # Degenerate: the piece lies within the zero circle (the goal is walled in);
        # fast marching has no zero contour there, the straight line is exact.
        out[piece] = phi[piece] + radius
        return out
    # The piece is connected and holds both signs, so it has a zero contour.
    d = skfmm.distance(np.ma.MaskedArray(phi, mask=~piece), dx=res, order=2)
    out[piece] = np.asarray(d.filled(np.inf))[piece] + radius
    return out
