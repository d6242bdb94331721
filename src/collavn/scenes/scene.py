"""The frozen `Scene`: triangles with materials, the floor, and a navigation grid.

One representation serves procedural apartments and imported meshes alike, so the
renderer and the simulator never care where a scene came from. World frame: metres,
Z up, the chosen floor at ``floor_z``.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
import zlib
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Any

import numpy as np

from collavn.errors import SceneError
from collavn.files import atomic_write
from collavn.scenes.limits import SizeLimits
from collavn.scenes.navigation import GeodesicField, NavConfig, NavGrid
from collavn.scenes.spec import SceneSpec

#: Bumped whenever the on-disk layout of a saved scene changes (2: a content checksum).
SCENE_FORMAT_VERSION = 2
#: Saved-scene formats :meth:`Scene.load` reads (1: without a checksum, read unchecked).
READABLE_SCENE_FORMATS = (1, 2)


@dataclass(frozen=True, eq=False)
class Scene:
    """An indoor environment, ready to render and to navigate.

    Attributes:
        name: Human-readable identity, e.g. ``procedural:3`` or a file name.
        vertices: ``(V, 3)`` float32 vertex positions in metres, Z up.
        faces: ``(F, 3)`` int32 vertex indices per triangle.
        face_uvs: ``(F, 3, 2)`` float32 texture coordinates of each triangle corner,
            OpenGL convention (u to the right, v up); textures tile (coordinates
            wrap modulo 1). The texel for ``(u, v)`` is
            ``textures[m, S - 1 - floor(frac(v)·S), floor(frac(u)·S)]``.
        face_material: ``(F,)`` int32 index into ``textures``.
        face_tint: ``(F, 3)`` uint8 colour multiplied with the texture sample
            (material base colour or averaged vertex colours; white for pure textures).
        textures: ``(M, S, S, 3)`` uint8 square textures, one per material.
        floor_z: Height of the floor the agents drive on.
        nav: The navigation grid computed for that floor.
        source: Where the scene came from (``procedural:SEED`` or a resolved path).
        spec: How it was loaded (source and load options): ``load_scene(scene.spec)``
            rebuilds it. ``None`` for scenes built directly (builder, tests).
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    face_uvs: np.ndarray
    face_material: np.ndarray
    face_tint: np.ndarray
    textures: np.ndarray
    floor_z: float
    nav: NavGrid
    source: str = ""
    spec: SceneSpec | None = None
    _fields: dict[tuple[float, float], GeodesicField] = field(
        default_factory=dict, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        f = self.faces.shape[0]
        checks = [
            (self.vertices.ndim == 2 and self.vertices.shape[1] == 3, "vertices must be (V, 3)"),
            (self.faces.ndim == 2 and self.faces.shape[1] == 3, "faces must be (F, 3)"),
            (self.face_uvs.shape == (f, 3, 2), "face_uvs must be (F, 3, 2)"),
            (self.face_material.shape == (f,), "face_material must be (F,)"),
            (self.face_tint.shape == (f, 3), "face_tint must be (F, 3)"),
            (self.textures.ndim == 4 and self.textures.shape[3] == 3, "textures: (M, S, S, 3)"),
        ]
        for ok, message in checks:
            if not ok:
                raise SceneError(f"scene {self.name!r}: {message}")
        if f == 0:
            raise SceneError(f"scene {self.name!r} has no triangles")
        if f and (self.faces.min() < 0 or self.faces.max() >= len(self.vertices)):
            raise SceneError(f"scene {self.name!r}: a face indexes a missing vertex")
        if f and self.face_material.max() >= len(self.textures):
            raise SceneError(f"scene {self.name!r}: a face uses a missing material")
        if not np.isfinite(self.vertices).all():
            raise SceneError(f"scene {self.name!r}: vertices contain NaN or inf")

    # ------------------------------------------------------------------ geometry
    @property
    def num_triangles(self) -> int:
        """Number of triangles."""
        return int(self.faces.shape[0])

    @property
    def bounds(self) -> np.ndarray:
        """``(2, 3)`` axis-aligned bounds: ``[[xmin, ymin, zmin], [xmax, ymax, zmax]]``."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])

    @cached_property
    def triangles(self) -> np.ndarray:
        """``(F, 3, 3)`` float32 corner positions of every triangle."""
        return np.ascontiguousarray(self.vertices[self.faces], dtype=np.float32)

    @cached_property
    def face_normals(self) -> np.ndarray:
        """``(F, 3)`` float32 unit normals (zero for degenerate triangles)."""
        t = self.triangles.astype(np.float64)
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return (n / np.where(norm > 0, norm, 1.0)).astype(np.float32)

    @cached_property
    def content_hash(self) -> str:
        """SHA-256 over geometry, appearance and navigation: the scene's identity."""
        h = hashlib.sha256()
        for a in (self.vertices, self.faces, self.face_uvs, self.face_material,
                  self.face_tint, self.textures, self.nav.navigable):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr((round(self.floor_z, 6), self.nav.config)).encode())
        return h.hexdigest()

    # ---------------------------------------------------------------- navigation
    def geodesic_field(self, goal: np.ndarray | tuple[float, float]) -> GeodesicField:
        """Geodesic distance field to ``goal`` (x, y); cached per goal in memory."""
        g = np.asarray(goal, dtype=np.float64).reshape(2)
        key = (round(float(g[0]), 4), round(float(g[1]), 4))
        cached = self._fields.get(key)
        if cached is None:
            if len(self._fields) >= 256:
                self._fields.pop(next(iter(self._fields)))
            cached = self._fields[key] = self.nav.geodesic_field(g)
        return cached

    def geodesic_distance(self, start: np.ndarray | tuple[float, float],
                          goal: np.ndarray | tuple[float, float]) -> float:
        """Shortest navigable distance in metres; ``inf`` if not connected."""
        return float(self.geodesic_field(goal).distance(np.asarray(start).reshape(1, 2))[0])

    def shortest_path(self, start: np.ndarray | tuple[float, float],
                      goal: np.ndarray | tuple[float, float]) -> np.ndarray:
        """``(K, 2)`` waypoints from ``start`` to ``goal`` along the geodesic."""
        return self.geodesic_field(goal).path_from(np.asarray(start, dtype=np.float64))

    # --------------------------------------------------------------- persistence
    def save(self, path: str | Path) -> None:
        """Write the scene to an ``.npz`` file (atomically, with a content checksum)."""
        path = Path(path)
        buf = io.BytesIO()
        arrays: dict[str, Any] = dict(
            version=np.int64(SCENE_FORMAT_VERSION),
            name=np.array(self.name), source=np.array(self.source),
            spec=np.array(json.dumps(self.spec.to_dict()) if self.spec else ""),
            vertices=self.vertices, faces=self.faces, face_uvs=self.face_uvs,
            face_material=self.face_material, face_tint=self.face_tint,
            textures=self.textures, floor_z=np.float64(self.floor_z),
            **self.nav.to_arrays(),
        )
        arrays["checksum"] = np.array(_checksum(arrays))
        np.savez_compressed(buf, **arrays)
        atomic_write(path, buf.getvalue())

    @classmethod
    def load(cls, path: str | Path) -> Scene:
        """Read a scene written by :meth:`save`.

        Raises:
            SceneError: unreadable, another format, or damaged (the checksum of its
                arrays does not match).
        """
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                version = int(z["version"])
                if version not in READABLE_SCENE_FORMATS:
                    raise SceneError(f"{path}: scene format {version}, expected "
                                     f"{SCENE_FORMAT_VERSION}")
                arrays = {k: z[k] for k in z.files}
            stored = str(arrays.pop("checksum", ""))
            if version >= 2 and stored != _checksum(arrays):
                raise SceneError(f"saved scene {path} is damaged: its content does not "
                                 f"match its checksum")
            spec_text = str(arrays.get("spec", ""))  # absent in scenes saved before specs
            spec = SceneSpec.from_dict(json.loads(spec_text)) if spec_text else None
        except SceneError:
            raise
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile,
                zlib.error) as e:
            raise SceneError(f"cannot read saved scene {path}: {e}") from e
        return cls(
            name=str(arrays["name"]), source=str(arrays["source"]), spec=spec,
            vertices=arrays["vertices"], faces=arrays["faces"],
            face_uvs=arrays["face_uvs"], face_material=arrays["face_material"],
            face_tint=arrays["face_tint"], textures=arrays["textures"],
            floor_z=float(arrays["floor_z"]), nav=NavGrid.from_arrays(arrays),
        )


def _checksum(arrays: dict[str, Any]) -> str:
    """SHA-256 over every array's name, dtype, shape and bytes, in name order."""
    h = hashlib.sha256()
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        h.update(repr((name, a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    return h.hexdigest()


def build_scene(name: str, vertices: np.ndarray, faces: np.ndarray, face_uvs: np.ndarray,
                face_material: np.ndarray, face_tint: np.ndarray, textures: np.ndarray,
                floor_z: float, nav_config: NavConfig | None = None,
                source: str = "", limits: SizeLimits | None = None) -> Scene:
    """Assemble a :class:`Scene` from arrays and compute its navigation grid.

    Raises:
        SceneError: malformed arrays, a grid above ``limits``, or no navigable floor.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float32)
    faces = np.ascontiguousarray(faces, dtype=np.int32)
    triangles = vertices[faces]
    nav = NavGrid.from_triangles(triangles, floor_z, nav_config or NavConfig(), name=name,
                                 limits=limits)
    return Scene(
        name=name, vertices=vertices, faces=faces,
        face_uvs=np.ascontiguousarray(face_uvs, dtype=np.float32),
        face_material=np.ascontiguousarray(face_material, dtype=np.int32),
        face_tint=np.ascontiguousarray(face_tint, dtype=np.uint8),
        textures=np.ascontiguousarray(textures, dtype=np.uint8),
        floor_z=float(floor_z), nav=nav, source=source,
    )
