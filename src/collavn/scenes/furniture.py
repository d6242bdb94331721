"""Furniture for procedural apartments: a catalogue of items and their placement.

Each item is drawn in a local frame ``(u, d, z)``: ``u`` runs along the wall the item
backs onto, ``d`` away from it into the room. Rotations are multiples of 90°, so the
boxes stay axis-aligned. Placement keeps the room navigable by construction: items
keep :data:`GAP` from each other and from door zones, and an item either stands
flush against walls or keeps :data:`GAP` from them, so no pocket traps the robot.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from collavn.scenes import textures as tx
from collavn.scenes.builder import SceneBuilder
from collavn.scenes.floorplan import Rect

#: Free space kept between items and in front of doors: the 0.36 m robot passes.
GAP = 0.8
_SIDES = (0, 1, 2, 3)  # the wall an item backs onto: y0, y1, x0, x1
_NO_BOTTOM = (1, 2, 3, 4, 5)
_LEGS = (2, 3, 4, 5)
# Local face (z-, z+, d-, d+, u-, u+) → world face of SceneBuilder.add_box, per side.
_FACE_MAP = ((0, 1, 2, 3, 4, 5), (0, 1, 3, 2, 5, 4), (0, 1, 4, 5, 3, 2), (0, 1, 5, 4, 2, 3))


@dataclass(frozen=True)
class Materials:
    """Material indices shared by all furniture of a scene."""

    wood: int
    wood_dark: int
    white: int
    metal: int
    black: int
    fabrics: tuple[int, ...]
    bedding: int
    stone: int
    ceramic: int
    plant: int
    pot: int
    books: int
    rugs: tuple[int, ...]


def furniture_materials(builder: SceneBuilder, rng: np.random.Generator) -> Materials:
    """Register the furniture materials (19 textures) with ``builder``."""
    s = builder.texture_size

    def mat(name: str, fn: tx.TextureFn) -> int:
        return builder.material(name, fn(rng, s))

    def solid(name: str, rgb: tuple[float, float, float]) -> int:
        noise = tx.periodic_noise(rng, s, 1.0)
        shaded = np.asarray(rgb) * (0.94 + 0.08 * noise[..., None])
        return builder.material(name, tx.to_uint8(shaded))

    return Materials(
        wood=mat("wood", tx.wood), wood_dark=mat("wood_dark", tx.wood),
        white=solid("white", (0.9, 0.9, 0.88)), metal=solid("metal", (0.62, 0.64, 0.66)),
        black=solid("black", (0.08, 0.08, 0.09)),
        fabrics=tuple(mat(f"fabric{i}", tx.fabric) for i in range(3)),
        bedding=mat("bedding", tx.checks), stone=mat("stone", tx.marble),
        ceramic=solid("ceramic", (0.95, 0.95, 0.96)),
        plant=builder.material("plant", tx.to_uint8(
            tx.hsv_to_rgb(0.3, 0.7, 0.2 + 0.4 * tx.periodic_noise(rng, s, 1.2)))),
        pot=solid("pot", (0.66, 0.33, 0.2)), books=mat("books", tx.book_spines),
        rugs=tuple(mat(f"rug{i}", fn) for i, fn in enumerate((tx.carpet, tx.damask,
                                                               tx.checks))))


class Frame:
    """Local frame of one placed item: maps ``(u, d)`` to world ``(x, y)``.

    ``rect`` is the item's world footprint and ``side`` the wall it backs onto
    (0: ``y = y0``, 1: ``y = y1``, 2: ``x = x0``, 3: ``x = x1``). Box faces are named
    locally like :meth:`SceneBuilder.add_box` names them in the world: 0 bottom, 1 top,
    2 towards the wall (d-), 3 into the room (d+), 4 and 5 the ends (u-, u+). Viewed
    from the room (looking along -d), +u points to the left.
    """

    def __init__(self, builder: SceneBuilder, rect: Rect, side: int) -> None:
        self.builder, self.rect, self.side = builder, rect, side
        along_x = side in (0, 1)
        self.length = rect.width if along_x else rect.height
        self.depth = rect.height if along_x else rect.width

    def xy(self, u: float, d: float) -> tuple[float, float]:
        """World position of local ``(u, d)``."""
        r = self.rect
        return ((r.x0 + u, r.y0 + d), (r.x1 - u, r.y1 - d),
                (r.x0 + d, r.y1 - u), (r.x1 - d, r.y0 + u))[self.side]

    def box(self, u0: float, d0: float, z0: float, u1: float, d1: float, z1: float,
            material: int, faces: tuple[int, ...] = _NO_BOTTOM, tile: float = 0.6) -> None:
        """An axis-aligned box between local corners ``(u0, d0, z0)`` and ``(u1, d1, z1)``."""
        (xa, ya), (xb, yb) = self.xy(u0, d0), self.xy(u1, d1)
        world = tuple(_FACE_MAP[self.side][f] for f in faces)
        self.builder.add_box((min(xa, xb), min(ya, yb), z0), (max(xa, xb), max(ya, yb), z1),
                             material, tile=tile, faces=world)

    def quad(self, u0: float, u1: float, d: float, z0: float, z1: float, material: int) -> None:
        """A picture quad at depth ``d`` facing into the room (texture stretched once)."""
        (xa, ya), (xb, yb) = self.xy(u1, d), self.xy(u0, d)
        corners = np.array([[xa, ya, z0], [xb, yb, z0], [xb, yb, z1], [xa, ya, z1]])
        self.builder.add_quad(corners, material)

    def cylinder(self, u: float, d: float, radius: float, z0: float, z1: float,
                 material: int) -> None:
        """A vertical cylinder centred at local ``(u, d)``."""
        self.builder.add_cylinder(self.xy(u, d), radius, z0, z1, material, segments=8)

    def table(self, u0: float, d0: float, u1: float, d1: float, height: float,
              top: int, legs: int) -> None:
        """A table top on four thin legs (5 cm square)."""
        self.box(u0, d0, height - 0.04, u1, d1, height, top, faces=(0, 1, 2, 3, 4, 5))
        for u in (u0 + 0.04, u1 - 0.09):
            for d in (d0 + 0.04, d1 - 0.09):
                self.box(u, d, 0.0, u + 0.05, d + 0.05, height - 0.04, legs, faces=_LEGS)

    def chair(self, u: float, d: float, facing_up: bool, m: Materials) -> None:
        """A chair with a 0.42 m seat whose lower-left corner is ``(u, d)``."""
        self.table(u, d, u + 0.42, d + 0.42, 0.46, m.wood_dark, m.wood_dark)
        back = (d, d + 0.05) if facing_up else (d + 0.37, d + 0.42)
        self.box(u, back[0], 0.46, u + 0.42, back[1], 0.92, m.wood_dark,
                 faces=(0, 1, 2, 3, 4, 5))


# ---------------------------------------------------------------- the items
DrawFn = Callable[[Frame, Materials, np.random.Generator], None]


def _sofa(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    cloth = m.fabrics[int(rng.integers(len(m.fabrics)))]
    L, D = f.length, f.depth
    f.box(0.0, 0.0, 0.0, L, D, 0.42, cloth)
    f.box(0.0, 0.0, 0.42, L, 0.22, 0.85, cloth)
    for u0 in (0.0, L - 0.18):
        f.box(u0, 0.22, 0.42, u0 + 0.18, D, 0.62, cloth)


def _coffee_table(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    f.table(0.0, 0.0, f.length, f.depth, 0.45, m.wood_dark if rng.random() < 0.5 else m.stone,
            m.wood_dark)


def _tv_stand(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    f.box(0.0, 0.0, 0.0, f.length, f.depth, 0.5, m.wood)
    mid, half = f.length / 2, min(0.6, f.length / 2 - 0.05)
    f.box(mid - half, 0.1, 0.55, mid + half, 0.15, 1.25, m.black, faces=(0, 1, 2, 3, 4, 5))
    f.box(mid - 0.1, 0.08, 0.5, mid + 0.1, 0.17, 0.55, m.black)


def _shelf(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    L, D, H = f.length, f.depth, float(rng.uniform(1.8, 2.1))
    wood = m.wood if rng.random() < 0.5 else m.wood_dark
    f.box(0.0, 0.0, 0.0, L, 0.02, H, wood, faces=(3,))
    for u0 in (0.0, L - 0.03):
        f.box(u0, 0.0, 0.0, u0 + 0.03, D, H, wood)
    levels = np.linspace(0.0, H - 0.03, int(rng.integers(4, 7)))
    for z in levels:
        f.box(0.03, 0.02, z, L - 0.03, D, z + 0.03, wood, faces=(0, 1, 3))
    for z0, z1 in zip(levels[:-1] + 0.03, levels[1:], strict=True):
        f.box(0.05, 0.03, z0, L - 0.05, D - 0.06, z0 + 0.85 * (z1 - z0), m.books,
              faces=(3,), tile=0.85 * (z1 - z0))


def _wardrobe(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    L, D = f.length, f.depth
    f.box(0.0, 0.0, 0.0, L, D, 2.1, m.wood if rng.random() < 0.5 else m.white)
    for u in (L / 2 - 0.08, L / 2 + 0.05):
        f.box(u, D, 0.9, u + 0.03, D + 0.03, 1.3, m.metal)


def _bed(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    L, D = f.length, f.depth
    f.box(0.0, 0.0, 0.0, L, D, 0.3, m.wood_dark)
    f.box(0.0, 0.0, 0.0, L, 0.06, 1.0, m.wood_dark)
    f.box(0.05, 0.06, 0.3, L - 0.05, D - 0.05, 0.5, m.white, faces=(1,))
    f.box(0.05, 0.65, 0.5, L - 0.05, D - 0.02, 0.54, m.bedding, tile=1.0)
    pillows = ((0.12, L / 2 - 0.05), (L / 2 + 0.05, L - 0.12)) if L > 1.2 else ((0.12, L - 0.12),)
    for u0, u1 in pillows:
        f.box(u0, 0.12, 0.5, u1, 0.5, 0.62, m.white)


def _nightstand(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    f.box(0.0, 0.0, 0.0, f.length, f.depth, 0.55, m.wood)
    u, d = f.length / 2, f.depth / 2
    f.cylinder(u, d, 0.06, 0.55, 0.85, m.metal)
    f.cylinder(u, d, 0.15, 0.85, 1.05, m.fabrics[int(rng.integers(len(m.fabrics)))])


def _desk(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    f.table(0.0, 0.0, f.length, 0.65, 0.74, m.wood if rng.random() < 0.5 else m.white, m.metal)
    f.chair(f.length / 2 - 0.21, 0.75, facing_up=False, m=m)


def _dining(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    L, D = f.length, f.depth
    f.table(0.0, 0.45, L, D - 0.45, 0.75, m.wood, m.wood)
    seats = max(1, int((L - 0.1) // 0.65))
    for k in range(seats):
        u = (k + 0.5) * L / seats - 0.21
        f.chair(u, 0.0, facing_up=True, m=m)
        f.chair(u, D - 0.42, facing_up=False, m=m)


def _counter(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    L, D = f.length, f.depth
    f.box(0.0, 0.0, 0.0, L, D - 0.03, 0.86, m.white if rng.random() < 0.5 else m.wood)
    f.box(0.0, 0.0, 0.86, L, D, 0.9, m.stone)
    f.box(0.0, 0.0, 1.45, L, 0.35, 2.1, m.wood, faces=(0, 1, 2, 3, 4, 5))
    hob = float(rng.uniform(0.1, max(0.1, L - 0.7)))
    f.box(hob, 0.05, 0.9, hob + 0.6, D - 0.05, 0.91, m.black)


def _fridge(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    f.box(0.0, 0.0, 0.0, f.length, f.depth, 1.85, m.metal if rng.random() < 0.5 else m.white)


def _bathtub(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    L, D = f.length, f.depth
    f.box(0.0, 0.0, 0.0, L, D, 0.55, m.ceramic)
    f.box(0.08, 0.08, 0.55, L - 0.08, D - 0.08, 0.56, m.metal, faces=(1,))


def _toilet(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    f.box(0.0, 0.0, 0.0, f.length, 0.2, 0.8, m.ceramic)
    f.cylinder(f.length / 2, 0.42, 0.19, 0.0, 0.42, m.ceramic)


def _vanity(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    L, D = f.length, f.depth
    f.box(0.0, 0.0, 0.0, L, D, 0.8, m.wood)
    f.box(0.0, 0.0, 0.8, L, D, 0.86, m.ceramic)
    f.box(0.1, 0.0, 1.1, L - 0.1, 0.02, 1.8, m.metal, faces=(3,))


def _plant(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    u, d = f.length / 2, f.depth / 2
    f.cylinder(u, d, 0.17, 0.0, 0.35, m.pot)
    f.cylinder(u, d, 0.24, 0.35, float(rng.uniform(0.9, 1.5)), m.plant)


def _cabinet(f: Frame, m: Materials, rng: np.random.Generator) -> None:
    f.box(0.0, 0.0, 0.0, f.length, f.depth, float(rng.uniform(0.8, 1.0)),
          m.wood_dark if rng.random() < 0.5 else m.white)


@dataclass(frozen=True)
class Item:
    """A kind of furniture: how to draw it, its size ranges and where it stands."""

    draw: DrawFn
    length: tuple[float, float]
    depth: tuple[float, float]
    height: float
    against_wall: bool = True


SOFA = Item(_sofa, (1.6, 2.4), (0.85, 0.95), 0.85)
ARMCHAIR = Item(_sofa, (0.8, 0.9), (0.8, 0.9), 0.85)
COFFEE_TABLE = Item(_coffee_table, (0.9, 1.3), (0.5, 0.7), 0.45, against_wall=False)
TV_STAND = Item(_tv_stand, (1.3, 1.8), (0.4, 0.45), 1.25)
SHELF = Item(_shelf, (0.8, 1.6), (0.32, 0.38), 2.1)
WARDROBE = Item(_wardrobe, (1.0, 2.0), (0.55, 0.62), 2.1)
BED = Item(_bed, (0.9, 1.8), (1.95, 2.1), 1.0)
NIGHTSTAND = Item(_nightstand, (0.4, 0.5), (0.38, 0.42), 1.05)
DESK = Item(_desk, (1.0, 1.6), (1.2, 1.25), 0.92)
DINING = Item(_dining, (1.3, 2.2), (1.75, 2.0), 0.92, against_wall=False)
COUNTER = Item(_counter, (1.8, 3.6), (0.6, 0.62), 2.1)
FRIDGE = Item(_fridge, (0.6, 0.7), (0.62, 0.68), 1.85)
BATHTUB = Item(_bathtub, (1.5, 1.7), (0.7, 0.75), 0.56)
TOILET = Item(_toilet, (0.4, 0.42), (0.65, 0.7), 0.8)
VANITY = Item(_vanity, (0.6, 1.0), (0.45, 0.5), 1.8)
PLANT = Item(_plant, (0.5, 0.5), (0.5, 0.5), 1.5)
CABINET = Item(_cabinet, (0.8, 1.3), (0.32, 0.45), 1.0)

#: What each room type may contain: (item, probability), most important first.
RECIPES: dict[str, tuple[tuple[Item, float], ...]] = {
    "living": ((SOFA, 1.0), (TV_STAND, 0.9), (COFFEE_TABLE, 0.9), (SHELF, 0.8),
               (ARMCHAIR, 0.6), (PLANT, 0.7), (ARMCHAIR, 0.3), (CABINET, 0.4)),
    "kitchen": ((COUNTER, 1.0), (FRIDGE, 0.9), (COUNTER, 0.6), (DINING, 0.6), (PLANT, 0.3)),
    "bedroom": ((BED, 1.0), (WARDROBE, 0.9), (NIGHTSTAND, 0.8), (NIGHTSTAND, 0.5),
                (DESK, 0.4), (SHELF, 0.3), (PLANT, 0.3)),
    "bathroom": ((TOILET, 1.0), (VANITY, 1.0), (BATHTUB, 0.8), (CABINET, 0.4)),
    "dining": ((DINING, 1.0), (CABINET, 0.8), (PLANT, 0.6), (SHELF, 0.4), (PLANT, 0.3)),
    "office": ((DESK, 1.0), (SHELF, 0.9), (SHELF, 0.5), (ARMCHAIR, 0.4), (PLANT, 0.5)),
    "library": ((SHELF, 1.0), (SHELF, 1.0), (SHELF, 0.8), (ARMCHAIR, 0.9), (ARMCHAIR, 0.6),
                (COFFEE_TABLE, 0.5), (PLANT, 0.4)),
    "hall": ((CABINET, 0.7), (PLANT, 0.6), (PLANT, 0.4)),
}


#: Extra items for large rooms: one per 14 m² of floor.
FILLERS = (SHELF, CABINET, PLANT, ARMCHAIR)
#: Room types that may have a rug.
RUG_ROOMS = frozenset({"living", "bedroom", "office", "library", "dining"})


@dataclass(frozen=True)
class Placed:
    """An item in the room: world footprint, the wall it backs onto, its height."""

    rect: Rect
    side: int
    height: float


def furnish(builder: SceneBuilder, m: Materials, kind: str, interior: Rect,
            keep_clear: list[Rect], rng: np.random.Generator) -> list[Placed]:
    """Place and draw the furniture of one room.

    Args:
        builder: Receives the geometry.
        m: Shared furniture materials.
        kind: Room type, a key of :data:`RECIPES`.
        interior: The room's floor inside its walls.
        keep_clear: Areas no item may come within :data:`GAP` of (door zones).
        rng: Random generator.

    Returns:
        The placed items, for instance to keep pictures off tall furniture.
    """
    if kind in RUG_ROOMS and rng.random() < 0.7:
        _rug(builder, m, interior, rng)
    placed: list[Placed] = []
    recipe = RECIPES.get(kind, ())
    extra = rng.integers(len(FILLERS), size=int(interior.area // 14))
    fillers = [(FILLERS[int(k)], 0.8) for k in extra]
    for item, prob in (*recipe, *fillers):
        if rng.random() >= prob:
            continue
        for _ in range(12):
            spot = _propose(item, interior, rng)
            if spot is None:
                continue
            rect, side = spot
            if not any(rect.near(other, GAP) for other in keep_clear + [p.rect for p in placed]):
                item.draw(Frame(builder, rect, side), m, rng)
                placed.append(Placed(rect, side, item.height))
                break
    return placed


def _rug(builder: SceneBuilder, m: Materials, room: Rect, rng: np.random.Generator) -> None:
    """A flat rug (1.2 cm high, below the robot's step height) near the room centre."""
    w, h = room.width * rng.uniform(0.35, 0.6), room.height * rng.uniform(0.35, 0.6)
    cx = room.center[0] + rng.uniform(-0.15, 0.15) * (room.width - w)
    cy = room.center[1] + rng.uniform(-0.15, 0.15) * (room.height - h)
    builder.add_box((cx - w / 2, cy - h / 2, 0.0), (cx + w / 2, cy + h / 2, 0.012),
                    m.rugs[int(rng.integers(len(m.rugs)))], tile=float(min(w, h)), faces=(1,))


def _propose(item: Item, room: Rect, rng: np.random.Generator) -> tuple[Rect, int] | None:
    """A random footprint: backed onto a wall (snapped into a near corner) or free."""
    side = int(rng.choice(_SIDES))
    along_x = side in (0, 1)
    span = room.width if along_x else room.height
    cross = room.height if along_x else room.width
    length = min(float(rng.uniform(*item.length)), span - GAP - 0.2)
    depth = float(rng.uniform(*item.depth))
    if length < item.length[0] - 0.3 or depth > cross - GAP - 0.2:
        return None
    if item.against_wall:
        u0 = float(rng.uniform(0.0, span - length))
        u0 = 0.0 if u0 < GAP else span - length if span - length - u0 < GAP else u0
        d0 = 0.0
    else:
        if span - length < 2 * GAP or cross - depth < 2 * GAP:
            return None
        u0 = float(rng.uniform(GAP, span - length - GAP))
        d0 = float(rng.uniform(GAP, cross - depth - GAP))
    lo = (room.x0 + u0, room.y0 + d0) if along_x else (room.x0 + d0, room.y0 + u0)
    size = (length, depth) if along_x else (depth, length)
    rect = Rect(lo[0], lo[1], lo[0] + size[0], lo[1] + size[1])
    if side == 1 and item.against_wall:
        rect = Rect(rect.x0, room.y1 - depth, rect.x1, room.y1)
    if side == 3 and item.against_wall:
        rect = Rect(room.x1 - depth, rect.y0, room.x1, rect.y1)
    return rect, side
