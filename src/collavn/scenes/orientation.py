"""Which way is up: choose a mesh's up axis, rotate it to Z up, and warn when it looks wrong.

``auto`` takes the axis a file declares (COLLADA ``<up_axis>``); otherwise the axis
along which the scene is clearly thinnest (indoor scenes are wider than they are
tall), and the format's convention when neither axis is clearly thinner. Only Y and
Z are detected; X up must be asked for. Whatever was chosen, a loaded scene that
looks implausible (little navigable area for its footprint, a floor far below the
geometry, a building tens of metres tall) gets one warning that names the options.
"""

from __future__ import annotations

import warnings

import numpy as np

from collavn.errors import SceneWarning
from collavn.scenes.scene import Scene

#: An axis is "clearly thinnest" when the other candidate is this many times longer.
THINNER = 1.5
#: Warn when less than this share of the footprint is navigable.
MIN_NAVIGABLE_SHARE = 0.05
#: Warn when the median vertex lies more than this far above the floor (metres).
MAX_FLOOR_DEPTH = 5.0
#: Warn when the scene is taller than this (metres): likely the wrong unit.
MAX_HEIGHT = 50.0
#: Warn when a scene taller than this (metres) is also taller than it is wide.
TALL = 4.0


def choose_up_axis(vertices: np.ndarray, requested: str, declared: str | None,
                   prior: str, name: str) -> tuple[str, str]:
    """The up axis to use and why (``requested``, ``declared by the file``, ``detected``).

    Args:
        vertices: ``(V, 3)`` coordinates as in the file (scaled).
        requested: ``auto``, ``x``, ``y`` or ``z``.
        declared: The file's own up axis, if it states one.
        prior: The format's convention, used when the geometry is ambiguous.
        name: For the warning when file and geometry disagree.
    """
    if requested != "auto":
        return requested, "requested"
    thin = thinnest_axis(vertices)
    if declared is not None:
        if thin is not None and thin != declared:
            warnings.warn(
                f"{name}: the file declares {declared.upper()} up but the geometry is "
                f"thinnest along {thin.upper()}; using {declared.upper()} as declared. If "
                f"the scene comes out sideways, load it with up_axis={thin!r} (--up-axis "
                f"{thin})", SceneWarning, stacklevel=3)
        return declared, "declared by the file"
    if thin is None:
        return prior, "the format's convention (geometry ambiguous)"
    return thin, "detected from the geometry"


def thinnest_axis(vertices: np.ndarray) -> str | None:
    """``y`` or ``z`` if the ``(V, 3)`` points are clearly thinnest along it, else ``None``."""
    extent = vertices.max(axis=0) - vertices.min(axis=0)
    ey, ez = float(extent[1]), float(extent[2])
    if ez * THINNER <= ey:
        return "z"
    if ey * THINNER <= ez:
        return "y"
    return None


def to_z_up(vertices: np.ndarray, up_axis: str) -> np.ndarray:
    """Rotate ``(V, 3)`` points so that ``up_axis`` becomes +Z (a proper rotation)."""
    x, y, z = vertices[:, 0], vertices[:, 1], vertices[:, 2]
    if up_axis == "y":
        return np.stack([x, -z, y], axis=1)
    if up_axis == "x":
        return np.stack([y, z, x], axis=1)
    return vertices


def warn_if_implausible(scene: Scene, up_axis: str, reason: str) -> None:
    """Warn once if ``scene`` looks loaded with the wrong up axis, unit or floor.

    Checks: the navigable area against the xy footprint, the floor against the
    median vertex height, and the height (alone, and against the width: a room
    loaded on its side is taller than it is wide).
    """
    lo, hi = scene.bounds
    width, depth, height = (float(v) for v in hi - lo)
    nav = scene.nav
    area = float(nav.navigable.sum()) * nav.resolution**2
    footprint = max(width * depth, 1e-9)
    above = float(np.median(scene.vertices[:, 2])) - scene.floor_z
    problems = []
    if height > MAX_HEIGHT:
        problems.append(f"it is {height:,.0f} m tall (centimetres? load with scale=0.01)")
    elif height > TALL and height > min(width, depth):
        problems.append(f"it is taller ({height:.1f} m) than it is wide "
                        f"({min(width, depth):.1f} m)")
    if area < MIN_NAVIGABLE_SHARE * footprint:
        problems.append(f"only {area:.0f} m² of its {width:.1f} × {depth:.1f} m footprint "
                        f"({100 * area / footprint:.1f} %) is navigable")
    if above > MAX_FLOOR_DEPTH:
        problems.append(f"the floor at z = {scene.floor_z:.2f} m lies {above:.0f} m below "
                        f"most of the geometry")
    if not problems:
        return
    others = ", ".join(repr(a) for a in ("z", "y", "x") if a != up_axis)
    warnings.warn(
        f"{scene.name} looks wrong: {'; '.join(problems)}. It was loaded with up axis "
        f"{up_axis.upper()} ({reason}); try up_axis={others} (--up-axis), scale= for the "
        f"unit, or floor_height= for another storey", SceneWarning, stacklevel=3)
