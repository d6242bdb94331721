"""Import real scenes from mesh files (``.glb .gltf .obj .ply .dae``) through trimesh.

Textures, material base colours and vertex colours are kept; textures are resampled
to one square size so the renderer can index them as one ``(M, S, S, 3)`` array.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from collavn.errors import SceneError, SceneWarning
from collavn.scenes.limits import SizeLimits
from collavn.scenes.mesh_files import read_facts
from collavn.scenes.navigation import NavConfig
from collavn.scenes.orientation import choose_up_axis, to_z_up, warn_if_implausible
from collavn.scenes.scene import Scene, build_scene
from collavn.scenes.spec import SceneSpec, UpAxis

MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".dae")


def load_mesh_scene(path: str | Path, *, up_axis: UpAxis = "auto", scale: float = 1.0,
                    floor_height: float | None = None, texture_size: int = 128,
                    nav_config: NavConfig | None = None,
                    limits: SizeLimits | None = None) -> Scene:
    """Load a mesh file as a :class:`Scene` (metres, Z up).

    The load options mean what the fields of :class:`~collavn.scenes.spec.SceneSpec`
    say; :func:`collavn.scenes.load_scene` is the usual way in.

    Args:
        path: Mesh file; ``.glb/.gltf/.obj/.ply/.dae``.
        up_axis: ``auto`` (the file's declaration, else the geometry), ``x``, ``y``
            or ``z``: the file's axis that points up.
        scale: Multiplies coordinates after the file's own unit (COLLADA ``<unit>``).
        floor_height: Pick the floor nearest this height (multi-floor buildings);
            default: the lowest floor with a substantial area.
        texture_size: Side of the square textures (texels).
        nav_config: Navigation parameters.
        limits: Largest extent and navigation grid accepted (checked before the grid
            is allocated).

    Raises:
        SceneError: missing file, unreadable or empty mesh, a mesh too large for
            ``limits``, or no floor.
    """
    path = Path(path)
    spec = SceneSpec(str(path), up_axis=up_axis, scale=scale, floor_height=floor_height)
    if not path.exists():
        raise SceneError(f"mesh file not found: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{path}: unsupported mesh format {path.suffix!r}; "
                         f"expected one of {', '.join(MESH_SUFFIXES)}")
    facts = read_facts(path)
    if facts.missing_textures:
        missing = ", ".join(facts.missing_textures)
        warnings.warn(f"{path}: texture file(s) not found: {missing}; those surfaces render "
                      f"in their material colour (often plain white)", SceneWarning,
                      stacklevel=2)
    parts = _read_parts(path)
    vertices, faces, uvs, mats, tints, textures = _merge(parts, texture_size)
    vertices = vertices * (facts.unit * spec.scale)
    axis, reason = choose_up_axis(vertices, spec.up_axis, facts.up_axis, facts.prior_up,
                                  str(path))
    vertices = to_z_up(vertices, axis)
    (limits or SizeLimits()).check_extent(vertices, str(path))
    floor_z = _pick_floor(path, find_floors(vertices[faces]), spec, axis)
    scene = build_scene(path.name, vertices, faces, uvs, mats, tints, textures, floor_z,
                        nav_config, source=str(path.resolve()), limits=limits)
    warn_if_implausible(scene, axis, reason)
    return scene


def _pick_floor(path: Path, floors: list[float], spec: SceneSpec, axis: str) -> float:
    """The floor height to use, or an error that says what to try."""
    if not floors:
        others = " or ".join(repr(a) for a in ("z", "y", "x") if a != axis)
        raise SceneError(f"{path}: no horizontal floor surface found with {axis.upper()} up; "
                         f"if the file is oriented otherwise, try up_axis={others}")
    target = spec.floor_height
    if target is None:
        return floors[0]
    floor_z = min(floors, key=lambda z: abs(z - target))
    if abs(floor_z - target) > 0.25:
        raise SceneError(
            f"{path}: no floor at height {target:.2f} m; floors found at "
            + ", ".join(f"{z:.2f}" for z in floors) + " m")
    return floor_z


def find_floors(triangles: np.ndarray, bin_size: float = 0.05,
                min_fraction: float = 0.25) -> list[float]:
    """Heights of floor-like surfaces, lowest first.

    A floor is a height bin whose upward-facing triangle area is at least
    ``min_fraction`` of the largest such bin; adjacent bins are merged and floors
    closer than 1.5 m are treated as one.

    Args:
        triangles: ``(F, 3, 3)`` corners, Z up.
        bin_size: Height bin in metres.
        min_fraction: A bin needs this share of the largest bin's area.
    """
    t = triangles.astype(np.float64)
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    area = 0.5 * np.linalg.norm(n, axis=1)
    up = (n[:, 2] > 0.95 * np.linalg.norm(n, axis=1)) & (area > 0)
    if not up.any():
        return []
    z = t[up, :, 2].mean(axis=1)
    idx = np.floor((z - z.min()) / bin_size).astype(np.int64)
    hist = np.bincount(idx, weights=area[up])
    strong = np.nonzero(hist >= min_fraction * hist.max())[0]
    floors: list[float] = []
    for b in strong:
        sel = idx == b
        height = float(np.average(z[sel], weights=area[up][sel]))
        if floors and height - floors[-1] < 1.5:
            continue
        floors.append(height)
    return floors


# ------------------------------------------------------------------ internals
def _read_parts(path: Path) -> list[Any]:
    import trimesh

    try:
        loaded: Any = trimesh.load(str(path), force="scene")
        parts = [g for g in loaded.dump(concatenate=False)
                 if isinstance(g, trimesh.Trimesh) and len(g.faces)]
    except Exception as e:  # trimesh raises many types on corrupt input
        raise SceneError(f"cannot read mesh {path}: {type(e).__name__}: {e}") from e
    if not parts:
        raise SceneError(f"{path}: the file contains no triangles")
    return parts


def _merge(parts: list[Any], size: int) -> tuple[np.ndarray, ...]:
    """Concatenate trimesh parts into scene arrays with a shared texture table."""
    textures = [np.full((size, size, 3), 255, dtype=np.uint8)]  # 0: plain white
    by_image: dict[int, int] = {}
    vs, fs, uvs, mats, tints = [], [], [], [], []
    offset = 0
    for part in parts:
        v = np.asarray(part.vertices, dtype=np.float64)
        f = np.asarray(part.faces, dtype=np.int64)
        uv, material, tint = _appearance(part, size, textures, by_image)
        vs.append(v)
        fs.append(f + offset)
        uvs.append(uv[f] if uv is not None else np.zeros((len(f), 3, 2)))
        mats.append(np.full(len(f), material, dtype=np.int32))
        tints.append(tint[f].mean(axis=1) if tint.ndim == 2 and len(tint) == len(v)
                     else np.broadcast_to(tint, (len(f), 3)))
        offset += len(v)
    vertices = np.concatenate(vs)
    return (vertices, np.concatenate(fs), np.concatenate(uvs), np.concatenate(mats),
            np.clip(np.concatenate(tints), 0, 255).astype(np.uint8), np.stack(textures))


def _appearance(part: Any, size: int, textures: list[np.ndarray],
                by_image: dict[int, int]) -> tuple[np.ndarray | None, int, np.ndarray]:
    """UVs per vertex (or None), material index and tint (per vertex or one colour)."""
    visual = part.visual
    kind = getattr(visual, "kind", None)
    if kind == "vertex":
        return None, 0, np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3]
    if kind == "face":
        colors = np.asarray(visual.face_colors, dtype=np.float64)[:, :3]
        per_vertex = np.zeros((len(part.vertices), 3))
        per_vertex[part.faces.ravel()] = np.repeat(colors, 3, axis=0)
        return None, 0, per_vertex
    material = getattr(visual, "material", None)
    tint = np.array([200.0, 200.0, 200.0])  # untextured, uncoloured: light grey
    image = None
    if material is not None:
        factor = getattr(material, "baseColorFactor", None)
        if factor is None:
            factor = getattr(material, "diffuse", None)
        if factor is not None:
            tint = np.asarray(factor, dtype=np.float64)[:3]
            if tint.max() <= 1.0:
                tint = tint * 255.0
        image = getattr(material, "baseColorTexture", None) or getattr(material, "image", None)
    uv = getattr(visual, "uv", None)
    if image is None or uv is None or len(uv) != len(part.vertices):
        return None, 0, tint
    key = id(image)
    if key not in by_image:
        by_image[key] = len(textures)
        rgb = image.convert("RGB")
        # Atlases of a few flat texels must not bleed into each other when enlarged.
        small = rgb.width <= size and rgb.height <= size
        rgb = rgb.resize((size, size), Image.Resampling.NEAREST if small else Image.Resampling.BOX)
        textures.append(np.asarray(rgb, dtype=np.uint8))
    return np.asarray(uv, dtype=np.float64), by_image[key], tint
