"""Import real scenes from mesh files (``.glb .gltf .obj .ply .dae``) through trimesh.

Textures, material base colours and vertex colours are kept; textures are resampled
to one square size so the renderer can index them as one ``(M, S, S, 3)`` array.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from collavn.errors import SceneError
from collavn.scenes.navigation import NavConfig
from collavn.scenes.scene import Scene, build_scene

MESH_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".dae")


def load_mesh_scene(path: str | Path, *, up_axis: str = "z", scale: float = 1.0,
                    floor_height: float | None = None, texture_size: int = 128,
                    nav_config: NavConfig | None = None) -> Scene:
    """Load a mesh file as a :class:`Scene`.

    Args:
        path: Mesh file; ``.glb/.gltf/.obj/.ply/.dae``.
        up_axis: ``"z"`` (Gibson ``mesh_z_up.obj``, and what trimesh returns for the
            shared test scenes) or ``"y"`` (glTF convention, e.g. HM3D); the result is
            always Z up.
        scale: Multiplies coordinates (e.g. 0.01 for centimetre files).
        floor_height: Pick the floor nearest this height (multi-floor buildings);
            default: the lowest floor with a substantial area.
        texture_size: Side of the square textures (texels).
        nav_config: Navigation parameters.

    Raises:
        SceneError: missing file, unreadable or empty mesh, or no floor.
    """
    path = Path(path)
    if not path.exists():
        raise SceneError(f"mesh file not found: {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise SceneError(f"{path}: unsupported mesh format {path.suffix!r}; "
                         f"expected one of {', '.join(MESH_SUFFIXES)}")
    if up_axis not in ("z", "y"):
        raise SceneError(f"up_axis must be 'z' or 'y', got {up_axis!r}")
    if not np.isfinite(scale) or scale <= 0:
        raise SceneError(f"scale must be a positive number, got {scale}")
    parts = _read_parts(path)
    vertices, faces, uvs, mats, tints, textures = _merge(parts, texture_size)
    vertices = vertices * scale
    if up_axis == "y":
        vertices = np.stack([vertices[:, 0], -vertices[:, 2], vertices[:, 1]], axis=1)
    floors = find_floors(vertices[faces])
    if not floors:
        hint = " (is it Y-up? try up_axis='y')" if up_axis == "z" else ""
        raise SceneError(f"{path}: no horizontal floor surface found{hint}")
    if floor_height is None:
        floor_z = floors[0]
    else:
        floor_z = min(floors, key=lambda z: abs(z - floor_height))
        if abs(floor_z - floor_height) > 0.25:
            raise SceneError(
                f"{path}: no floor at height {floor_height:.2f} m; floors found at "
                + ", ".join(f"{z:.2f}" for z in floors) + " m")
    return build_scene(path.name, vertices, faces, uvs, mats, tints, textures, floor_z,
                       nav_config, source=str(path.resolve()))


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
    if not np.isfinite(vertices).all():
        raise SceneError("mesh vertices contain NaN or inf")
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
