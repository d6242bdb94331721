"""Turn a scene spec (``procedural:SEED`` or a mesh path) into a cached :class:`Scene`."""

from __future__ import annotations

import hashlib
import os
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from collavn.errors import SceneError
from collavn.scenes.navigation import NavConfig
from collavn.scenes.scene import SCENE_FORMAT_VERSION, Scene

#: Bump when procedural generation changes, so cached apartments are rebuilt.
PROCEDURAL_VERSION = 1


def default_cache_dir() -> Path:
    """``$COLLAVN_CACHE`` if set, else ``~/.cache/collavn``."""
    env = os.environ.get("COLLAVN_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "collavn"


def parse_scene_spec(spec: str) -> tuple[str, str]:
    """Split a spec into its kind (``procedural``, ``saved`` or ``mesh``) and its value.

    The value is the seed's digits for ``procedural:SEED`` and the path otherwise.
    """
    if spec.startswith("procedural:"):
        text = spec.split(":", 1)[1]
        try:
            seed = int(text)
        except ValueError:
            raise SceneError(f"bad scene spec {spec!r}: the seed must be an integer, "
                             f"e.g. procedural:0") from None
        if seed < 0:
            raise SceneError(f"bad scene spec {spec!r}: the seed must be ≥ 0")
        return "procedural", str(seed)
    if spec.endswith(".npz"):
        return "saved", spec
    return "mesh", spec


def load_scene(spec: str, *, cache: bool = True, cache_dir: str | Path | None = None,
               nav_config: NavConfig | None = None, **options: Any) -> Scene:
    """Load a scene by spec, using the on-disk cache when possible.

    Args:
        spec: ``procedural:SEED``, a path to a ``.glb/.gltf/.obj/.ply/.dae`` file, or
            an ``.npz`` written by :meth:`Scene.save`.
        cache: Read and write the processed scene (geometry, textures, navigation
            grid) under ``cache_dir``; keyed by the file's content and all options.
        cache_dir: Defaults to :func:`default_cache_dir`.
        nav_config: Navigation parameters (robot radius, grid resolution, ...).
        **options: Passed to :func:`collavn.scenes.procedural.generate_apartment` or
            :func:`collavn.scenes.meshes.load_mesh_scene` (e.g. ``up_axis="y"``).
    """
    kind, value = parse_scene_spec(spec)
    if kind == "saved":  # a scene written by Scene.save: nothing to process or cache
        if not Path(value).is_file():
            raise SceneError(f"saved scene not found: {value}")
        # Its source becomes this file, so episode files made from it can find it again.
        return replace(Scene.load(value), source=str(Path(value).resolve()))
    nav_config = nav_config or NavConfig()
    key = hashlib.sha256()
    key.update(repr((SCENE_FORMAT_VERSION, kind, sorted(options.items()),
                     sorted(asdict(nav_config).items()))).encode())
    if kind == "procedural":
        key.update(f"procedural-v{PROCEDURAL_VERSION}:{value}".encode())
        stem = f"procedural-{value}"
    else:
        path = Path(value)
        if not path.is_file():
            raise SceneError(f"scene file not found: {path}")
        key.update(path.read_bytes())
        stem = path.stem
    cached = Path(cache_dir or default_cache_dir()) / f"{stem}-{key.hexdigest()[:16]}.npz"
    if cache and cached.is_file():
        try:
            return Scene.load(cached)
        except SceneError:
            cached.unlink(missing_ok=True)  # stale or damaged cache: rebuild below
    scene = _build(kind, value, nav_config, options)
    if cache:
        try:
            scene.save(cached)
        except OSError:
            pass  # a read-only cache directory only costs speed
    return scene


def _build(kind: str, value: str, nav_config: NavConfig,
           options: dict[str, Any]) -> Scene:
    if kind == "procedural":
        from collavn.scenes.procedural import generate_apartment

        return generate_apartment(int(value), nav_config=nav_config, **options)
    from collavn.scenes.meshes import load_mesh_scene

    return load_mesh_scene(Path(value), nav_config=nav_config, **options)
