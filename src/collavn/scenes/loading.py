"""Turn a :class:`SceneSpec` (or its source string) into a cached :class:`Scene`."""

from __future__ import annotations

import hashlib
import os
import warnings
from dataclasses import asdict, replace
from pathlib import Path
from typing import Any

from collavn.errors import SceneError, SceneWarning
from collavn.scenes.limits import SizeLimits
from collavn.scenes.navigation import NavConfig
from collavn.scenes.scene import SCENE_FORMAT_VERSION, Scene
from collavn.scenes.spec import SceneSpec, parse_scene_spec

__all__ = ["cache_path", "default_cache_dir", "load_scene", "parse_scene_spec"]

#: Bump when procedural generation changes, so cached apartments are rebuilt.
PROCEDURAL_VERSION = 1
#: Bump when mesh import changes its result for the same file and options.
MESH_IMPORT_VERSION = 2


def default_cache_dir() -> Path:
    """``$COLLAVN_CACHE`` if set, else ``~/.cache/collavn``."""
    env = os.environ.get("COLLAVN_CACHE")
    return Path(env) if env else Path.home() / ".cache" / "collavn"


def load_scene(scene: str | Path | SceneSpec, *, cache: bool = True,
               cache_dir: str | Path | None = None, nav_config: NavConfig | None = None,
               limits: SizeLimits | None = None, **options: Any) -> Scene:
    """Load a scene, using the on-disk cache when possible.

    ``load_scene("procedural:3")``, ``load_scene("hall.dae")``,
    ``load_scene("scan.obj", up_axis="y", scale=0.01)`` and
    ``load_scene(SceneSpec("scan.obj", up_axis="y", scale=0.01))`` are the ways in;
    the last two are the same load. The returned scene records the spec it was loaded
    with (``scene.spec``, source made absolute), so ``load_scene(scene.spec)`` loads it
    again.

    Args:
        scene: A :class:`SceneSpec` or its source: ``procedural:SEED``, a path to a
            ``.glb/.gltf/.obj/.ply/.dae`` file, or an ``.npz`` from :meth:`Scene.save`.
        cache: Read and write the processed scene (geometry, textures, navigation
            grid) under ``cache_dir``, keyed by :func:`cache_path`.
        cache_dir: Defaults to :func:`default_cache_dir`.
        nav_config: Navigation parameters (robot radius, grid resolution, ...).
        limits: Largest mesh extent and navigation grid to accept (default
            :class:`SizeLimits`); not part of the cache key.
        **options: Load options of :class:`SceneSpec` (``up_axis``, ``scale``,
            ``floor_height``), replacing those of ``scene``.

    Raises:
        SceneError: a bad spec, a missing or unreadable file, a scene larger than
            ``limits``, or no floor.
    """
    spec = SceneSpec.of(scene, **options).resolved()
    if spec.kind == "saved":  # a scene written by Scene.save: nothing to process or cache
        if not Path(spec.source).is_file():
            raise SceneError(f"saved scene not found: {spec.source}")
        # Its source becomes this file, so episode files made from it can find it again.
        return replace(Scene.load(spec.source), source=spec.source, spec=spec)
    if spec.kind == "mesh" and not Path(spec.source).is_file():
        raise SceneError(f"scene file not found: {spec.source}")
    nav_config = nav_config or NavConfig()
    cached = cache_path(spec, nav_config, cache_dir)
    if cache and cached.is_file():
        try:
            return _with_spec(Scene.load(cached), spec)
        except SceneError as e:  # damaged (or unreadable) cache file: rebuild it
            warnings.warn(f"rebuilding the cached scene {spec.source}: {e}", SceneWarning,
                          stacklevel=2)
            cached.unlink(missing_ok=True)
    built = _with_spec(_build(spec, nav_config, limits), spec)
    if cache:
        try:
            built.save(cached)
        except OSError:
            pass  # a read-only cache directory only costs speed
    return built


def cache_path(spec: SceneSpec, nav_config: NavConfig,
               cache_dir: str | Path | None = None) -> Path:
    """Where the processed scene of ``spec`` is cached: the one definition of the key.

    The key covers the scene format, the procedural generator or mesh importer
    version, the file's content (not its path), every load option and the
    navigation parameters; ``procedural:3`` and ``SceneSpec("procedural:3")`` share it.
    """
    key = hashlib.sha256()
    options = spec.to_dict()
    del options["source"]
    key.update(repr((SCENE_FORMAT_VERSION, spec.kind, sorted(options.items()),
                     sorted(asdict(nav_config).items()))).encode())
    if spec.kind == "procedural":
        seed = parse_scene_spec(spec.source)[1]
        key.update(f"procedural-v{PROCEDURAL_VERSION}:{seed}".encode())
        stem = f"procedural-{seed}"
    else:
        path = Path(spec.source)
        key.update(f"mesh-v{MESH_IMPORT_VERSION}{path.suffix.lower()}".encode())
        with path.open("rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                key.update(block)
        stem = path.stem
    return Path(cache_dir or default_cache_dir()) / f"{stem}-{key.hexdigest()[:16]}.npz"


def _with_spec(scene: Scene, spec: SceneSpec) -> Scene:
    """``scene`` recording ``spec`` (and its source) as where it came from."""
    if scene.spec == spec and scene.source == spec.source:
        return scene
    return replace(scene, source=spec.source, spec=spec)


def _build(spec: SceneSpec, nav_config: NavConfig, limits: SizeLimits | None) -> Scene:
    if spec.kind == "procedural":
        from collavn.scenes.procedural import generate_apartment

        seed = int(parse_scene_spec(spec.source)[1])
        return generate_apartment(seed, nav_config=nav_config)
    from collavn.scenes.meshes import load_mesh_scene

    return load_mesh_scene(Path(spec.source), up_axis=spec.up_axis, scale=spec.scale,
                           floor_height=spec.floor_height, nav_config=nav_config,
                           limits=limits)
