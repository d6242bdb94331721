"""Procedural apartments: the default scene source, fully offline and deterministic.

``generate_apartment(seed)`` turns a seed into a furnished, textured apartment in
three declarative steps, each with its own random stream so that changing one
(say, the furniture) leaves the others as they were:

1. **plan** (:mod:`collavn.scenes.floorplan`): rooms, corridor and doors;
2. **shell**: per room a floor slab and walls with door gaps and lintels, each room
   with its own floor and wall textures chosen by room type; one ceiling;
3. **fittings** (:mod:`collavn.scenes.furniture`): furniture per room type, kept
   off doors, and framed paintings on free stretches of wall.

Same seed → bit-identical scene (equal ``content_hash``) on any machine.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from collavn.errors import SceneError
from collavn.scenes import textures as tx
from collavn.scenes.builder import SceneBuilder
from collavn.scenes.floorplan import WALL_THICKNESS, Door, FloorPlan, Rect, Room, plan_apartment
from collavn.scenes.furniture import Frame, Materials, Placed, furnish, furniture_materials
from collavn.scenes.navigation import NavConfig
from collavn.scenes.scene import Scene

#: Wall (and ceiling) height in metres.
WALL_HEIGHT = 2.6
#: Top of door openings in metres.
DOOR_HEIGHT = 2.1
#: Depth in metres of the area kept free of furniture on each side of a door.
DOOR_ZONE = 0.5
#: At most this many distinct painting textures per scene (more pictures reuse them).
MAX_PAINTINGS = 14

_FLOORS: dict[str, tuple[tx.TextureFn, ...]] = {
    "living": (tx.wood_floor, tx.wood_floor, tx.carpet), "kitchen": (tx.tiles,),
    "bathroom": (tx.tiles,), "bedroom": (tx.carpet, tx.wood_floor),
    "dining": (tx.wood_floor, tx.tiles), "office": (tx.wood_floor, tx.carpet),
    "library": (tx.wood_floor, tx.carpet), "hall": (tx.wood_floor, tx.tiles),
}
_WALLS: dict[str, tuple[tx.TextureFn, ...]] = {
    "living": (tx.plaster, tx.damask, tx.stripes, tx.brick),
    "kitchen": (tx.tiles, tx.plaster, tx.checks),
    "bathroom": (tx.tiles, tx.marble),
    "bedroom": (*tx.WALLPAPERS, tx.plaster),
    "dining": (tx.damask, tx.stripes, tx.plaster, tx.brick),
    "office": (tx.plaster, tx.stripes, tx.brick),
    "library": (tx.damask, tx.plaster, tx.checks),
    "hall": (tx.plaster, tx.dots, tx.stripes),
}
#: Metres covered by one repeat of each texture kind (default 1 m).
_TILE: dict[tx.TextureFn, float] = {tx.tiles: 0.8, tx.wood_floor: 1.4, tx.brick: 1.2,
                                    tx.carpet: 1.5, tx.marble: 1.2}


def apartment_plan(seed: int, *, min_rooms: int = 4, max_rooms: int = 12) -> FloorPlan:
    """The floor plan :func:`generate_apartment` uses for ``seed`` (rooms and doors)."""
    if seed < 0:
        raise SceneError(f"apartment seed must be ≥ 0, got {seed}")
    return plan_apartment(_streams(seed)[0], min_rooms, max_rooms)


def generate_apartment(seed: int, *, texture_size: int = 64,
                       nav_config: NavConfig | None = None, min_rooms: int = 4,
                       max_rooms: int = 12) -> Scene:
    """Generate the furnished apartment for ``seed``.

    Args:
        seed: Any integer ≥ 0; the scene is a pure function of it and the options.
        texture_size: Side ``S`` of the ``(S, S, 3)`` textures.
        nav_config: Navigation parameters (robot radius, grid resolution, ...).
        min_rooms: Fewest rooms (a corridor, if any, is not counted).
        max_rooms: Most rooms.

    Returns:
        A :class:`Scene` named ``procedural:SEED`` with its navigation grid; the
        floor is at ``z = 0``.
    """
    plan = apartment_plan(seed, min_rooms=min_rooms, max_rooms=max_rooms)
    _, look_rng, furniture_rng = _streams(seed)
    builder = SceneBuilder(texture_size)
    shared = furniture_materials(builder, look_rng)
    paintings = _Paintings(builder, look_rng)
    builder.add_box((plan.footprint.x0, plan.footprint.y0, WALL_HEIGHT),
                    (plan.footprint.x1, plan.footprint.y1, WALL_HEIGHT + 0.1),
                    builder.material("ceiling", _whiten(tx.plaster(look_rng, texture_size))),
                    faces=(0,))
    for index, room in enumerate(plan.rooms):
        _room(builder, plan, index, look_rng)
        interior = room.rect.shrink(WALL_THICKNESS / 2)
        zones = [d.zone(DOOR_ZONE) for d in plan.doors_of(index)]
        placed = furnish(builder, shared, room.kind, interior, zones, furniture_rng)
        _hang_pictures(builder, plan, index, placed, shared, paintings, furniture_rng)
    name = f"procedural:{seed}"
    return builder.build(name, floor_z=0.0, nav_config=nav_config, source=name)


def _whiten(texture: np.ndarray) -> np.ndarray:
    """Blend a ``(S, S, 3)`` uint8 texture 70 % towards white (ceilings)."""
    return (0.3 * texture + 0.7 * 245.0).astype(np.uint8)


def _streams(seed: int) -> list[np.random.Generator]:
    """Independent generators for plan, looks (textures) and furniture."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(3)]


# ------------------------------------------------------------------- shell
def _room(builder: SceneBuilder, plan: FloorPlan, index: int,
          rng: np.random.Generator) -> None:
    """Floor slab and walls (with door gaps) of one room, in its own materials."""
    room = plan.rooms[index]
    floor_fn = _FLOORS[room.kind][int(rng.integers(len(_FLOORS[room.kind])))]
    wall_fn = _WALLS[room.kind][int(rng.integers(len(_WALLS[room.kind])))]
    size = builder.texture_size
    floor = builder.material(f"floor{index}", floor_fn(rng, size))
    wall = builder.material(f"wall{index}", wall_fn(rng, size))
    r = room.rect
    builder.add_box((r.x0, r.y0, -0.1), (r.x1, r.y1, 0.0), floor,
                    tile=_TILE.get(floor_fn, 1.0), faces=(1,))
    for side in range(4):
        frame, gaps = _wall_frame(builder, plan, index, side)
        tile = _TILE.get(wall_fn, 1.0)
        depth = frame.depth
        cuts = [0.0, *[g for gap in gaps for g in gap], frame.length]
        for u0, u1 in zip(cuts[::2], cuts[1::2], strict=True):
            ends = (4,) * (u0 > 0) + (5,) * (u1 < frame.length)
            if u1 - u0 > 1e-6:
                frame.box(u0, 0.0, 0.0, u1, depth, WALL_HEIGHT, wall, faces=(3, *ends),
                          tile=tile)
        for u0, u1 in gaps:
            frame.box(u0, 0.0, DOOR_HEIGHT, u1, depth, WALL_HEIGHT, wall, faces=(0, 3),
                      tile=tile)


def _wall_frame(builder: SceneBuilder, plan: FloorPlan, index: int,
                side: int) -> tuple[Frame, list[tuple[float, float]]]:
    """The room's half of the wall on ``side`` as a local frame, and its door gaps.

    The half wall is ``WALL_THICKNESS / 2`` deep; on the apartment's outside it
    also extends outwards by as much, so outer walls have the full thickness.
    Gaps are ``(u0, u1)`` intervals in the frame's ``u`` coordinate, sorted.
    """
    r, fp = plan.rooms[index].rect, plan.footprint
    h = WALL_THICKNESS / 2
    line = (r.y0, r.y1, r.x0, r.x1)[side]
    out = h if line == (fp.y0, fp.y1, fp.x0, fp.x1)[side] else 0.0
    strip = (Rect(r.x0, r.y0 - out, r.x1, r.y0 + h), Rect(r.x0, r.y1 - h, r.x1, r.y1 + out),
             Rect(r.x0 - out, r.y0, r.x0 + h, r.y1), Rect(r.x1 - h, r.y0, r.x1 + out, r.y1))
    frame = Frame(builder, strip[side], side)
    axis = 1 if side in (0, 1) else 0
    gaps = sorted(_along(frame, d.lo, d.hi) for d in plan.doors_of(index)
                  if d.axis == axis and d.at == line)
    return frame, gaps


def _along(frame: Frame, lo: float, hi: float) -> tuple[float, float]:
    """World interval ``[lo, hi]`` along the frame's wall → local ``(u0, u1)``, u0 < u1."""
    r = frame.rect
    return ((lo - r.x0, hi - r.x0), (r.x1 - hi, r.x1 - lo),
            (r.y1 - hi, r.y1 - lo), (lo - r.y0, hi - r.y0))[frame.side]


# ---------------------------------------------------------------- pictures
@dataclass
class _Paintings:
    """Painting materials, made on demand; beyond :data:`MAX_PAINTINGS` they repeat."""

    builder: SceneBuilder
    rng: np.random.Generator
    ids: list[int] = field(default_factory=list)

    def next(self) -> int:
        """Material of the next painting to hang."""
        if len(self.ids) >= MAX_PAINTINGS:
            return self.ids[int(self.rng.integers(len(self.ids)))]
        texture = tx.painting(self.rng, self.builder.texture_size)
        self.ids.append(self.builder.material(f"painting{len(self.ids)}", texture))
        return self.ids[-1]


def _hang_pictures(builder: SceneBuilder, plan: FloorPlan, index: int, placed: list[Placed],
                   m: Materials, paintings: _Paintings, rng: np.random.Generator) -> None:
    """Hang 0–3 framed paintings on free wall: away from doors and tall furniture."""
    room = plan.rooms[index]
    wanted = int(rng.integers({"bathroom": 0}.get(room.kind, 1),
                              {"hall": 4, "bathroom": 2}.get(room.kind, 3)))
    hung: list[tuple[int, float, float]] = []
    for _ in range(8 * wanted):
        if len(hung) == wanted:
            break
        side = int(rng.integers(4))
        frame, gaps = _wall_frame(builder, plan, index, side)
        width = float(rng.uniform(0.5, 1.2))
        if frame.length < width + 1.0:
            continue
        c = float(rng.uniform(0.5 + width / 2, frame.length - 0.5 - width / 2))
        u0, u1 = c - width / 2, c + width / 2
        blocked = [(a - 0.25, b + 0.25) for a, b in gaps] + [
            (a, b) for s, a, b in hung if s == side] + _tall_items(frame, room, placed)
        if any(a < u1 + 0.1 and b > u0 - 0.1 for a, b in blocked):
            continue
        height = float(rng.uniform(0.4, 0.85))
        z0, z1 = 1.6 - height / 2, 1.6 + height / 2
        d = frame.depth
        frame.box(u0 - 0.05, d, z0 - 0.05, u1 + 0.05, d + 0.03, z1 + 0.05,
                  m.wood_dark if rng.random() < 0.6 else m.metal, faces=(0, 1, 3, 4, 5))
        frame.quad(u0, u1, d + 0.032, z0, z1, paintings.next())
        hung.append((side, u0, u1))


def _tall_items(frame: Frame, room: Room, placed: list[Placed]) -> list[tuple[float, float]]:
    """Local ``(u0, u1)`` of items taller than 1.1 m standing against this wall."""
    inner = room.rect.shrink(WALL_THICKNESS / 2)
    out = []
    for p in placed:
        touching = (abs(p.rect.y0 - inner.y0), abs(p.rect.y1 - inner.y1),
                    abs(p.rect.x0 - inner.x0), abs(p.rect.x1 - inner.x1))[frame.side] < 0.01
        if touching and p.height > 1.1:
            lo, hi = (p.rect.x0, p.rect.x1) if frame.side in (0, 1) else (p.rect.y0, p.rect.y1)
            out.append(_along(frame, lo, hi))
    return out


__all__ = ["Door", "FloorPlan", "Room", "apartment_plan", "generate_apartment"]
