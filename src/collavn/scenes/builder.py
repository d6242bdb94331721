"""A short declarative way to build scenes: boxes, cylinders and picture quads.

Used by the procedural apartments and by tests that need a hand-built scene with a
known answer (an L-shaped corridor, a wall with one door)::

    b = SceneBuilder(texture_size=64)
    wall = b.material("plaster", flat_texture((200, 200, 190), 64))
    b.add_box((0, 0, -0.1), (10, 2, 0.0), wall)        # floor slab
    b.add_box((0, 2, 0), (10, 2.1, 2.5), wall)          # a wall
    scene = b.build("corridor")
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

from collavn.errors import SceneError
from collavn.scenes.navigation import NavConfig
from collavn.scenes.scene import Scene, build_scene

# Per box face: 4 corner indices into the 8 box corners (counter-clockwise seen from
# outside) and the two world axes that span its texture coordinates.
_BOX_FACES = (
    ((0, 2, 3, 1), (1, 0)),  # z- (bottom)
    ((4, 5, 7, 6), (0, 1)),  # z+ (top)
    ((0, 1, 5, 4), (0, 2)),  # y-
    ((2, 6, 7, 3), (0, 2)),  # y+
    ((0, 4, 6, 2), (1, 2)),  # x-
    ((1, 3, 7, 5), (1, 2)),  # x+
)


def flat_texture(color: Sequence[int], size: int) -> np.ndarray:
    """``(size, size, 3)`` uint8 texture of one colour."""
    return np.broadcast_to(np.asarray(color, dtype=np.uint8), (size, size, 3)).copy()


class SceneBuilder:
    """Collects triangles with materials, then builds a :class:`Scene`."""

    def __init__(self, texture_size: int = 64) -> None:
        self.texture_size = texture_size
        self._textures: list[np.ndarray] = []
        self._names: dict[str, int] = {}
        self._tris: list[np.ndarray] = []
        self._uvs: list[np.ndarray] = []
        self._mats: list[np.ndarray] = []

    def material(self, name: str, texture: np.ndarray) -> int:
        """Register (or look up) a material by name; returns its index."""
        if name in self._names:
            return self._names[name]
        s = self.texture_size
        if texture.shape != (s, s, 3):
            raise SceneError(f"material {name!r}: texture must be ({s}, {s}, 3), "
                             f"got {texture.shape}")
        self._names[name] = len(self._textures)
        self._textures.append(np.ascontiguousarray(texture, dtype=np.uint8))
        return self._names[name]

    def add_triangles(self, triangles: np.ndarray, uvs: np.ndarray, material: int) -> None:
        """Add ``(T, 3, 3)`` triangles with ``(T, 3, 2)`` texture coordinates."""
        triangles = np.asarray(triangles, dtype=np.float64).reshape(-1, 3, 3)
        self._tris.append(triangles)
        self._uvs.append(np.asarray(uvs, dtype=np.float64).reshape(-1, 3, 2))
        self._mats.append(np.full(len(triangles), material, dtype=np.int32))

    def add_quad(self, corners: ArrayLike, material: int,
                 uv: np.ndarray | None = None) -> None:
        """Add a planar quad from 4 corners (counter-clockwise seen from its front).

        Without ``uv`` the texture is stretched once over the quad (a picture).
        """
        corners = np.asarray(corners, dtype=np.float64).reshape(4, 3)
        if uv is None:
            uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        idx = np.array([[0, 1, 2], [0, 2, 3]])
        self.add_triangles(corners[idx], np.asarray(uv)[idx], material)

    def add_box(self, lo: Sequence[float], hi: Sequence[float], material: int,
                tile: float = 1.0, faces: Sequence[int] = (0, 1, 2, 3, 4, 5)) -> None:
        """Add an axis-aligned box; the texture repeats every ``tile`` metres.

        ``faces`` selects which of the six sides (z-, z+, y-, y+, x-, x+) to emit.
        """
        lo_a, hi_a = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        if np.any(hi_a <= lo_a):
            raise SceneError(f"box with non-positive size: lo={lo_a}, hi={hi_a}")
        bits = np.array([[i & 1, (i >> 1) & 1, (i >> 2) & 1] for i in range(8)])
        corners = np.where(bits == 1, hi_a, lo_a)
        for f in faces:
            quad, (u_axis, v_axis) = _BOX_FACES[f]
            pts = corners[list(quad)]
            self.add_quad(pts, material, uv=pts[:, [u_axis, v_axis]] / tile)

    def add_cylinder(self, center: Sequence[float], radius: float, z0: float, z1: float,
                     material: int, segments: int = 12, tile: float = 1.0) -> None:
        """Add a closed vertical cylinder (table legs, lamps, bins)."""
        cx, cy = float(center[0]), float(center[1])
        a = np.linspace(0.0, 2 * np.pi, segments + 1)
        ring = np.stack([cx + radius * np.cos(a), cy + radius * np.sin(a)], axis=1)
        for k in range(segments):
            (x0, y0), (x1, y1) = ring[k], ring[k + 1]
            u0, u1 = radius * a[k] / tile, radius * a[k + 1] / tile
            self.add_quad([[x0, y0, z0], [x1, y1, z0], [x1, y1, z1], [x0, y0, z1]], material,
                          uv=np.array([[u0, z0], [u1, z0], [u1, z1], [u0, z1]]) / [1, tile])
            for z, order in ((z1, (0, 1)), (z0, (1, 0))):
                p = [[cx, cy, z], [*ring[k + order[0]], z], [*ring[k + order[1]], z]]
                self.add_triangles(np.array([p]), np.array([[(c[0] - cx) / tile,
                                                             (c[1] - cy) / tile]
                                                            for c in p]), material)

    def build(self, name: str, floor_z: float = 0.0, nav_config: NavConfig | None = None,
              source: str = "") -> Scene:
        """Finish: one indexed mesh plus its navigation grid."""
        if not self._tris:
            raise SceneError(f"scene {name!r} has no geometry")
        tris = np.concatenate(self._tris)
        vertices = tris.reshape(-1, 3)
        faces = np.arange(len(vertices), dtype=np.int32).reshape(-1, 3)
        mats = np.concatenate(self._mats)
        return build_scene(
            name, vertices, faces, np.concatenate(self._uvs), mats,
            np.full((len(tris), 3), 255, dtype=np.uint8), np.stack(self._textures),
            floor_z, nav_config, source=source or name,
        )
