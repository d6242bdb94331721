"""Floor plans of procedural apartments: rooms, a corridor and the doors between them.

A plan is pure data (no geometry), built in three declarative steps:

1. a footprint from 10 × 10 m to 30 × 30 m, optionally cut by a corridor;
2. binary space partitioning of the remaining area into rooms, then room types
   by size (the largest is the living room, the smallest a bathroom, ...);
3. doors on shared walls: a random spanning tree of the room adjacency graph
   (so every room is reachable), plus a few extra doors that make loops.

Rooms share boundaries exactly: a wall is centred on the boundary line.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from collavn.errors import SceneError

#: Wall thickness in metres (each room draws half of it on its side of a boundary).
WALL_THICKNESS = 0.12
#: Narrowest room side in metres.
MIN_ROOM_SIDE = 2.6
#: Door widths in metres: the 0.36 m robot passes with room to spare.
DOOR_WIDTH = (0.95, 1.25)
#: Space kept between a door and the wall corner next to it.
DOOR_MARGIN = WALL_THICKNESS / 2 + 0.15
#: Pairs of room types that may be joined by a wide opening instead of a door.
OPEN_PLAN = {frozenset({"living", "kitchen"}), frozenset({"living", "dining"}),
             frozenset({"kitchen", "dining"}), frozenset({"living", "hall"})}


@dataclass(frozen=True)
class Rect:
    """An axis-aligned rectangle ``[x0, x1] × [y0, y1]`` in metres."""

    x0: float
    y0: float
    x1: float
    y1: float

    @property
    def width(self) -> float:
        """Extent along x."""
        return self.x1 - self.x0

    @property
    def height(self) -> float:
        """Extent along y."""
        return self.y1 - self.y0

    @property
    def area(self) -> float:
        """Area in m²."""
        return self.width * self.height

    @property
    def center(self) -> tuple[float, float]:
        """Centre ``(x, y)``."""
        return (0.5 * (self.x0 + self.x1), 0.5 * (self.y0 + self.y1))

    def shrink(self, margin: float) -> Rect:
        """The rectangle moved inwards by ``margin`` on every side."""
        return Rect(self.x0 + margin, self.y0 + margin, self.x1 - margin, self.y1 - margin)

    def near(self, other: Rect, gap: float = 0.0) -> bool:
        """Whether the two rectangles overlap or are closer than ``gap``."""
        return not (other.x0 >= self.x1 + gap or other.x1 <= self.x0 - gap
                    or other.y0 >= self.y1 + gap or other.y1 <= self.y0 - gap)

    def contains(self, other: Rect) -> bool:
        """Whether ``other`` lies inside this rectangle."""
        return (self.x0 <= other.x0 + 1e-9 and other.x1 <= self.x1 + 1e-9
                and self.y0 <= other.y0 + 1e-9 and other.y1 <= self.y1 + 1e-9)


@dataclass(frozen=True)
class Room:
    """A room: its rectangle (walls centred on its border) and its type."""

    rect: Rect
    kind: str


@dataclass(frozen=True)
class Door:
    """An opening in the wall between rooms ``a`` and ``b``.

    Attributes:
        a: Index of one room.
        b: Index of the other room.
        axis: 0 if the wall is the vertical line ``x = at`` (the door spans y);
            1 if it is the horizontal line ``y = at`` (the door spans x).
        at: Position of the wall line.
        lo: Start of the opening along the wall.
        hi: End of the opening along the wall.
    """

    a: int
    b: int
    axis: int
    at: float
    lo: float
    hi: float

    @property
    def width(self) -> float:
        """Width of the opening in metres."""
        return self.hi - self.lo

    @property
    def center(self) -> tuple[float, float]:
        """Centre ``(x, y)`` of the opening on the wall line."""
        mid = 0.5 * (self.lo + self.hi)
        return (self.at, mid) if self.axis == 0 else (mid, self.at)

    def zone(self, depth: float, extra: float = 0.0) -> Rect:
        """The area within ``depth`` of the opening on both sides (kept free)."""
        lo, hi = self.lo - extra, self.hi + extra
        if self.axis == 0:
            return Rect(self.at - depth, lo, self.at + depth, hi)
        return Rect(lo, self.at - depth, hi, self.at + depth)


@dataclass(frozen=True)
class FloorPlan:
    """Rooms and doors of one apartment. ``footprint`` bounds all rooms."""

    footprint: Rect
    rooms: tuple[Room, ...]
    doors: tuple[Door, ...]

    def doors_of(self, room: int) -> list[Door]:
        """Doors that open into room ``room``."""
        return [d for d in self.doors if room in (d.a, d.b)]


def plan_apartment(rng: np.random.Generator, min_rooms: int = 4,
                   max_rooms: int = 12) -> FloorPlan:
    """Draw a connected floor plan with ``min_rooms``–``max_rooms`` rooms.

    The corridor, when there is one, is an extra room of type ``hall``.

    Raises:
        SceneError: if the room range is invalid or no connected plan was found.
    """
    if not 2 <= min_rooms <= max_rooms <= 40:
        raise SceneError(f"room range must satisfy 2 ≤ min ≤ max ≤ 40, "
                         f"got {min_rooms}..{max_rooms}")
    for _ in range(50):
        n = int(rng.integers(min_rooms, max_rooms + 1))
        footprint = _footprint(rng, n)
        regions, hall = _corridor(rng, footprint, n)
        rects = _partition(rng, regions, n)
        rooms = _room_types(rng, rects)
        if hall is not None:
            rooms.append(Room(hall, "hall"))
        doors = _doors(rng, rooms)
        if doors is not None:
            return FloorPlan(footprint, tuple(rooms), tuple(doors))
    raise SceneError("could not draw a connected floor plan (room range too tight?)")


# ----------------------------------------------------------------- layout
def _snap(x: float) -> float:
    """Round to 5 cm so plans are exact and shared boundaries compare equal."""
    return round(round(x / 0.05) * 0.05, 2)


def _footprint(rng: np.random.Generator, n: int) -> Rect:
    area = n * rng.uniform(14.0, 50.0)
    aspect = rng.uniform(0.65, 1.55)
    w = float(np.clip(np.sqrt(area * aspect), 10.0, 30.0))
    h = float(np.clip(area / w, 10.0, 30.0))
    return Rect(0.0, 0.0, _snap(w), _snap(h))


def _corridor(rng: np.random.Generator, fp: Rect,
              n: int) -> tuple[list[Rect], Rect | None]:
    """Maybe cut a full-length corridor along the long axis; returns regions and hall."""
    if n < 5 or rng.random() > 0.65:
        return [fp], None
    width = rng.uniform(1.4, 1.8)
    if fp.width >= fp.height:
        y = _snap(fp.y0 + rng.uniform(0.35, 0.65) * fp.height - width / 2)
        y1 = _snap(y + width)
        return [Rect(fp.x0, fp.y0, fp.x1, y), Rect(fp.x0, y1, fp.x1, fp.y1)], \
            Rect(fp.x0, y, fp.x1, y1)
    x = _snap(fp.x0 + rng.uniform(0.35, 0.65) * fp.width - width / 2)
    x1 = _snap(x + width)
    return [Rect(fp.x0, fp.y0, x, fp.y1), Rect(x1, fp.y0, fp.x1, fp.y1)], \
        Rect(x, fp.y0, x1, fp.y1)


def _cut(rng: np.random.Generator, r: Rect) -> tuple[Rect, Rect] | None:
    """Split a rectangle in two rooms no narrower than ``MIN_ROOM_SIDE``, if possible."""
    long_axis = 0 if r.width >= r.height else 1
    ratio = max(r.width, r.height) / min(r.width, r.height)
    axes = [long_axis, 1 - long_axis] if ratio > 1.3 or rng.random() < 0.6 \
        else [1 - long_axis, long_axis]
    for axis in axes:
        lo, hi = (r.x0, r.x1) if axis == 0 else (r.y0, r.y1)
        for frac in (rng.uniform(0.3, 0.7), 0.5):
            at = _snap(lo + frac * (hi - lo))
            if at - lo >= MIN_ROOM_SIDE and hi - at >= MIN_ROOM_SIDE:
                if axis == 0:
                    return Rect(r.x0, r.y0, at, r.y1), Rect(at, r.y0, r.x1, r.y1)
                return Rect(r.x0, r.y0, r.x1, at), Rect(r.x0, at, r.x1, r.y1)
    return None


def _partition(rng: np.random.Generator, regions: list[Rect], n: int) -> list[Rect]:
    """Split the regions until there are ``n`` rooms (or nothing can be split)."""
    leaves = list(regions)
    while len(leaves) < n:
        order = sorted(range(len(leaves)), key=lambda i: -leaves[i].area * rng.uniform(0.7, 1))
        for i in order:
            halves = _cut(rng, leaves[i])
            if halves is not None:
                leaves[i:i + 1] = list(halves)
                break
        else:
            break
    return leaves


def _room_types(rng: np.random.Generator, rects: list[Rect]) -> list[Room]:
    """Largest room: living; next: kitchen; smallest one or two: bathrooms; others mixed."""
    order = sorted(range(len(rects)), key=lambda i: -rects[i].area)
    kinds = ["living", "kitchen"]
    baths = 1 if len(rects) < 9 else 2
    middle = len(rects) - 2 - baths
    pool = ["bedroom", "bedroom", "dining", "office", "library", "bedroom", "office", "bedroom"]
    others = ["bedroom"] + [pool[k] for k in rng.permutation(len(pool))]
    kinds += others[:middle] + ["bathroom"] * baths
    kinds = kinds[:len(rects)]
    out: list[Room | None] = [None] * len(rects)
    for i, kind in zip(order, kinds, strict=True):
        out[i] = Room(rects[i], kind)
    return [r for r in out if r is not None]


# ------------------------------------------------------------------ doors
def _shared_wall(a: Rect, b: Rect) -> tuple[int, float, float, float] | None:
    """``(axis, at, lo, hi)`` of the boundary two rooms share, if any."""
    for axis, (a0, a1, b0, b1) in enumerate(((a.x0, a.x1, b.x0, b.x1),
                                              (a.y0, a.y1, b.y0, b.y1))):
        at = a1 if a1 == b0 else a0 if a0 == b1 else None
        if at is not None:
            lo, hi = (max(a.y0, b.y0), min(a.y1, b.y1)) if axis == 0 else \
                (max(a.x0, b.x0), min(a.x1, b.x1))
            if hi > lo:
                return axis, at, lo, hi
    return None


def _doors(rng: np.random.Generator, rooms: list[Room]) -> list[Door] | None:
    """Spanning tree (Kruskal on random weights, hubs preferred) plus extra doors."""
    edges = []
    for i in range(len(rooms)):
        for j in range(i + 1, len(rooms)):
            wall = _shared_wall(rooms[i].rect, rooms[j].rect)
            if wall is not None and wall[3] - wall[2] >= DOOR_WIDTH[1] + 2 * DOOR_MARGIN:
                hub = {rooms[i].kind, rooms[j].kind} & {"hall", "living"}
                edges.append((rng.random() - 0.8 * bool(hub), i, j, wall))
    edges.sort(key=lambda e: e[0])
    parent = list(range(len(rooms)))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    doors = []
    for _, i, j, wall in edges:
        bath = "bathroom" in (rooms[i].kind, rooms[j].kind)
        if root(i) != root(j):
            parent[root(i)] = root(j)
        elif bath or rng.random() > 0.25:
            continue
        doors.append(_door(rng, i, j, rooms, wall))
    if len({root(i) for i in range(len(rooms))}) > 1:
        return None
    return doors


def _door(rng: np.random.Generator, i: int, j: int, rooms: list[Room],
          wall: tuple[int, float, float, float]) -> Door:
    """A door of random width at a random place on the shared wall (5 cm grid)."""
    axis, at, lo, hi = wall
    width = rng.uniform(*DOOR_WIDTH)
    if frozenset({rooms[i].kind, rooms[j].kind}) in OPEN_PLAN and rng.random() < 0.5:
        width = min(rng.uniform(1.6, 2.6), hi - lo - 2 * DOOR_MARGIN)
    width = max(np.floor(width / 0.05) * 0.05, DOOR_WIDTH[0])
    first = np.ceil((lo + DOOR_MARGIN) / 0.05) * 0.05
    last = np.floor((hi - DOOR_MARGIN - width) / 0.05) * 0.05
    start = _snap(rng.uniform(first, last)) if last > first else _snap((lo + hi - width) / 2)
    return Door(i, j, axis, at, start, _snap(start + width))
