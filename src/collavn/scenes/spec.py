"""`SceneSpec`: which scene to load and how — the one description every entry point takes.

A spec is a source (``procedural:SEED``, a mesh file, or an ``.npz`` written by
:meth:`~collavn.scenes.scene.Scene.save`) plus the load options of a mesh file: its up
axis, a scale factor and which floor to use. ``load_scene``, the commands and the
episode datasets all take or record this one object, and the scene cache is keyed
by it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any, Literal, get_args

from collavn.errors import ConfigError, SceneError

UpAxis = Literal["auto", "x", "y", "z"]
#: Accepted values of :attr:`SceneSpec.up_axis`.
UP_AXES: tuple[str, ...] = get_args(UpAxis)
SceneKind = Literal["procedural", "saved", "mesh"]


def parse_scene_spec(source: str) -> tuple[SceneKind, str]:
    """Split a source into its kind (``procedural``, ``saved`` or ``mesh``) and its value.

    The value is the seed's digits for ``procedural:SEED`` and the path otherwise.

    Raises:
        SceneError: a procedural seed that is not a non-negative integer.
    """
    if source.startswith("procedural:"):
        text = source.split(":", 1)[1]
        try:
            seed = int(text)
        except ValueError:
            raise SceneError(f"bad scene spec {source!r}: the seed must be an integer, "
                             f"e.g. procedural:0") from None
        if seed < 0:
            raise SceneError(f"bad scene spec {source!r}: the seed must be ≥ 0")
        return "procedural", str(seed)
    if source.endswith(".npz"):
        return "saved", source
    return "mesh", source


@dataclass(frozen=True)
class SceneSpec:
    """A scene source and the options to load it with.

    Attributes:
        source: ``procedural:SEED``, a mesh file (``.glb .gltf .obj .ply .dae``) or a
            saved ``.npz`` scene.
        up_axis: Which axis of the file points up. ``auto`` (default) uses what the
            file declares (COLLADA ``<up_axis>``) and otherwise the geometry (the
            axis along which the scene is thinnest: buildings are wider than tall),
            with a warning when the result looks wrong. ``x``, ``y`` or ``z`` force it.
        scale: Multiplies coordinates after the file's own unit is applied (COLLADA
            ``<unit meter=…>``; glTF is metres; OBJ/PLY have no unit): e.g. 0.01 for
            an OBJ in centimetres.
        floor_height: Use the floor nearest this height in metres (after scaling),
            for multi-storey buildings; ``None`` = the lowest substantial floor.
    """

    source: str
    up_axis: UpAxis = "auto"
    scale: float = 1.0
    floor_height: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.source, str) or not self.source:
            raise SceneError(f"a scene source must be a non-empty string, got {self.source!r}")
        if self.up_axis not in UP_AXES:
            raise SceneError(f"up_axis must be one of {', '.join(UP_AXES)}, "
                             f"got {self.up_axis!r}")
        if not (_is_number(self.scale) and math.isfinite(self.scale) and self.scale > 0):
            raise SceneError(f"scale must be a finite positive number, got {self.scale!r}")
        if self.floor_height is not None and not (
                _is_number(self.floor_height) and math.isfinite(self.floor_height)):
            raise SceneError(f"floor_height must be a finite number of metres or None, "
                             f"got {self.floor_height!r}")
        if self.kind != "mesh" and self.options:
            raise SceneError(
                f"{self.source}: load options ({self.describe_options()}) only apply to "
                f"mesh files, not to a {self.kind} scene")

    # ------------------------------------------------------------ construction
    @classmethod
    def of(cls, scene: str | Path | SceneSpec, **options: Any) -> SceneSpec:
        """The spec for ``scene`` with ``options`` (``up_axis``, ``scale``, ``floor_height``).

        ``SceneSpec.of("house.dae", up_axis="y")`` equals
        ``SceneSpec("house.dae", up_axis="y")``; a spec given with options is copied
        with those options replaced.

        Raises:
            SceneError: an unknown option or an invalid value.
        """
        known = {f.name for f in fields(cls)} - {"source"}
        unknown = sorted(set(options) - known)
        if unknown:
            raise SceneError(f"unknown scene load option(s) {', '.join(unknown)}; "
                             f"expected {', '.join(sorted(known))}")
        if isinstance(scene, SceneSpec):
            return replace(scene, **options) if options else scene
        if isinstance(scene, Path):
            scene = str(scene)
        if not isinstance(scene, str):
            raise SceneError(f"a scene is a string or a SceneSpec, got {type(scene).__name__}")
        return cls(scene, **options)

    @classmethod
    def from_dict(cls, obj: dict[str, Any]) -> SceneSpec:
        """Inverse of :meth:`to_dict`.

        Raises:
            SceneError: a missing source, an unknown key or an invalid value.
        """
        if not isinstance(obj, dict) or "source" not in obj:
            raise SceneError(f"a recorded scene spec needs a 'source', got {obj!r}")
        rest = {k: v for k, v in obj.items() if k != "source"}
        return cls.of(obj["source"], **rest)

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON object with every field (defaults included)."""
        return {"source": self.source, "up_axis": self.up_axis, "scale": self.scale,
                "floor_height": self.floor_height}

    # ----------------------------------------------------------------- queries
    @property
    def kind(self) -> SceneKind:
        """``procedural``, ``saved`` (an ``.npz``) or ``mesh``."""
        return parse_scene_spec(self.source)[0]

    @property
    def options(self) -> dict[str, Any]:
        """The load options that differ from their defaults."""
        out: dict[str, Any] = {}
        if self.up_axis != "auto":
            out["up_axis"] = self.up_axis
        if self.scale != 1.0:
            out["scale"] = self.scale
        if self.floor_height is not None:
            out["floor_height"] = self.floor_height
        return out

    def describe_options(self) -> str:
        """``up_axis='y', scale=0.01`` or ``default options``, for messages."""
        items = [f"{k}={v!r}" for k, v in self.options.items()]
        return ", ".join(items) or "default options"

    def describe(self) -> str:
        """The source with every load option spelled out, for error messages."""
        if self.kind != "mesh":
            return self.source
        return (f"{self.source} (up_axis={self.up_axis!r}, scale={self.scale:g}, "
                f"floor_height={self.floor_height!r})")

    def resolved(self) -> SceneSpec:
        """The same spec with a file source made absolute (procedural ones unchanged)."""
        if self.kind == "procedural":
            return self
        return replace(self, source=str(Path(self.source).resolve()))

    def __str__(self) -> str:
        return self.source if not self.options else f"{self.source} ({self.describe_options()})"


def _is_number(value: object) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


@dataclass(frozen=True)
class LoadOptions:
    """The load options of a mesh file, as the commands take them (``--up-axis`` …).

    Attributes:
        up_axis: Which axis of the file points up: ``auto`` (what the file declares, else
            the geometry), ``x``, ``y`` or ``z``.
        scale: Multiplies coordinates after the file's own unit (0.01 for centimetres).
        floor_height: Use the floor nearest this height in metres (multi-storey meshes).
    """

    up_axis: UpAxis = "auto"
    """Which axis of a mesh file points up: ``auto`` (what the file says, else the
    geometry), ``x``, ``y`` or ``z``."""
    scale: float = 1.0
    """Multiply a mesh file's coordinates by this after its own unit (0.01: centimetres)."""
    floor_height: float | None = None
    """Multi-storey meshes: use the floor nearest this height in metres."""

    def __post_init__(self) -> None:
        try:
            SceneSpec("x.obj", self.up_axis, self.scale, self.floor_height)  # validates
        except SceneError as e:  # a bad flag: reported as a config error, not a tyro box
            raise ConfigError(str(e)) from None

    def spec(self, source: str | Path | SceneSpec) -> SceneSpec:
        """``source`` with these options; procedural and saved scenes take none.

        Raises:
            SceneError: options given for a scene that is not a mesh file.
        """
        options = SceneSpec("x.obj", self.up_axis, self.scale, self.floor_height).options
        return SceneSpec.of(source, **options)
