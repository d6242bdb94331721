"""Batched ray-cast rendering: 360° panoramas and goal views with depth, no OpenGL.

``Renderer(scene).render(poses)`` is the one way in; see :mod:`.renderer` for the
outputs and :mod:`.cameras` for the exact pixel → ray mapping.
"""

from collavn.rendering.cameras import CameraSpec
from collavn.rendering.renderer import Renderer, RenderOutput
from collavn.rendering.shading import BODY_PALETTE, BodySpec, Lighting

__all__ = ["BODY_PALETTE", "BodySpec", "CameraSpec", "Lighting", "RenderOutput", "Renderer"]
