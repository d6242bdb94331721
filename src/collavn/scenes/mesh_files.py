"""What a mesh file declares about itself, read before (and beside) trimesh.

trimesh returns coordinates as written: it ignores COLLADA's ``<unit>`` and
``<up_axis>``. This module reads those, notices Draco-compressed glTF (which needs
the optional decoder ``DracoPy``), and lists texture files a file refers to that
are not on disk (trimesh would silently render those surfaces white).
"""

from __future__ import annotations

import json
import re
import struct
import urllib.parse
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from collavn.errors import SceneError

DRACO = "KHR_draco_mesh_compression"


@dataclass(frozen=True)
class MeshFileFacts:
    """Declarations of one mesh file.

    Attributes:
        unit: Metres per file unit (COLLADA ``<unit meter=…>``; 1 for glTF, OBJ, PLY).
        up_axis: The declared up axis (``x``, ``y`` or ``z``), or ``None`` where the
            format states none that can be trusted (OBJ, PLY; glTF says Y but real
            exporters often write Z-up coordinates, so it is only a tie-breaker).
        prior_up: The axis to assume when the geometry is ambiguous.
        missing_textures: Texture files referred to but not found.
    """

    unit: float = 1.0
    up_axis: str | None = None
    prior_up: str = "z"
    missing_textures: tuple[str, ...] = ()


def read_facts(path: Path) -> MeshFileFacts:
    """Read the declarations of ``path`` (by suffix); raise if it cannot be decoded.

    Raises:
        SceneError: a Draco-compressed glTF while ``DracoPy`` is not installed.
    """
    suffix = path.suffix.lower()
    if suffix == ".dae":
        return _collada_facts(path)
    if suffix in (".glb", ".gltf"):
        return _gltf_facts(path)
    if suffix == ".obj":
        return MeshFileFacts(missing_textures=_missing(path.parent, _obj_textures(path)))
    return MeshFileFacts()


# ------------------------------------------------------------------ COLLADA
def _collada_facts(path: Path) -> MeshFileFacts:
    unit, up, images = 1.0, "y", []  # COLLADA defaults: metres, Y up
    try:
        for _, element in ET.iterparse(path, events=("end",)):
            tag = element.tag.rsplit("}", 1)[-1]
            if tag == "unit":
                unit = float(element.get("meter", "1"))
            elif tag == "up_axis" and element.text:
                up = element.text.strip()[0].lower()
            elif tag == "init_from" and element.text and _is_image(element.text):
                images.append(element.text.strip())
    except (ET.ParseError, ValueError, OSError) as e:
        raise SceneError(f"cannot read mesh {path}: malformed COLLADA: {e}") from e
    if not (unit > 0 and unit < float("inf")):
        raise SceneError(f"{path}: <unit meter={unit}> is not a positive length")
    if up not in ("x", "y", "z"):
        raise SceneError(f"{path}: unknown <up_axis> {up!r}")
    return MeshFileFacts(unit=unit, up_axis=up, prior_up=up,
                         missing_textures=_missing(path.parent, images))


def _is_image(text: str) -> bool:
    return bool(re.search(r"\.(png|jpe?g|bmp|tga|tiff?|gif|dds)$", text.strip(), re.I))


# --------------------------------------------------------------------- glTF
def _gltf_facts(path: Path) -> MeshFileFacts:
    doc = _gltf_json(path)
    used = set(doc.get("extensionsUsed", [])) | set(doc.get("extensionsRequired", []))
    if DRACO in used:
        try:
            import DracoPy  # noqa: F401
        except ImportError:
            raise SceneError(
                f"{path} is Draco-compressed ({DRACO}) and the decoder is not installed: "
                f"pip install DracoPy") from None
    uris = [img.get("uri", "") for img in doc.get("images", []) if isinstance(img, dict)]
    files = [urllib.parse.unquote(u) for u in uris if u and not u.startswith("data:")]
    return MeshFileFacts(prior_up="y", missing_textures=_missing(path.parent, files))


def _gltf_json(path: Path) -> dict[str, Any]:
    """The JSON chunk of a ``.glb`` or the whole ``.gltf``; ``{}`` if unreadable.

    An unreadable file is left to trimesh, whose error names the problem.
    """
    try:
        with path.open("rb") as f:
            head = f.read(20)
            if head[:4] == b"glTF":
                length, kind = struct.unpack("<II", head[12:20])
                if kind != 0x4E4F534A:  # "JSON"
                    return {}
                doc = json.loads(f.read(length))
            else:
                doc = json.loads(head + f.read())
    except (OSError, ValueError, struct.error):
        return {}
    return doc if isinstance(doc, dict) else {}


# ---------------------------------------------------------------------- OBJ
def _obj_textures(path: Path) -> list[str]:
    """Material libraries named by ``mtllib`` and the texture maps they name."""
    out: list[str] = []
    try:
        with path.open(errors="replace") as f:
            libs = [line.split(None, 1)[1].strip() for line in f if line.startswith("mtllib ")]
    except OSError:
        return out
    for lib in libs:
        mtl = path.parent / lib
        out.append(lib)
        if mtl.is_file():
            lines = mtl.read_text(errors="replace").splitlines()
            out += [str(Path(lib).parent / line.split()[-1]) for line in lines
                    if re.match(r"map_(Kd|Ka)\s", line.strip())]
    return out


def _missing(folder: Path, files: list[str]) -> tuple[str, ...]:
    """The entries of ``files`` (relative to ``folder`` unless absolute) not on disk."""
    gone = []
    for name in files:
        local = urllib.parse.urlparse(name).path if name.startswith("file:") else name
        if not (folder / local).is_file():
            gone.append(name)
    return tuple(dict.fromkeys(gone))
