"""Scenes: the frozen :class:`Scene`, procedural apartments, mesh import, navigation.

``load_scene("procedural:3")`` or ``load_scene("path/to/mesh.glb")`` is the one way in;
processed scenes are cached on disk so a second load is fast.
"""

from collavn.scenes.loading import default_cache_dir, load_scene, parse_scene_spec
from collavn.scenes.navigation import GeodesicField, NavConfig, NavGrid
from collavn.scenes.scene import Scene

__all__ = ["GeodesicField", "NavConfig", "NavGrid", "Scene", "default_cache_dir",
           "load_scene", "parse_scene_spec"]
