"""Scenes: the frozen :class:`Scene`, procedural apartments, mesh import, navigation.

``load_scene("procedural:3")``, ``load_scene("path/to/mesh.glb")`` or
``load_scene(SceneSpec("hall.obj", up_axis="y", scale=0.01))`` is the one way in;
processed scenes are cached on disk so a second load is fast.
"""

from collavn.scenes.limits import SizeLimits
from collavn.scenes.loading import default_cache_dir, load_scene
from collavn.scenes.navigation import GeodesicField, NavConfig, NavGrid
from collavn.scenes.scene import Scene
from collavn.scenes.spec import LoadOptions, SceneSpec, parse_scene_spec

__all__ = ["GeodesicField", "LoadOptions", "NavConfig", "NavGrid", "Scene", "SceneSpec",
           "SizeLimits", "default_cache_dir", "load_scene", "parse_scene_spec"]
