"""Procedural textures in pure NumPy: wood, tiles, carpet, plaster, wallpapers, paintings.

Every generator has the signature ``(rng, size) -> (size, size, 3) uint8`` and draws
all its randomness from the explicit ``rng``. Surface textures tile seamlessly: the
noise is filtered white noise in the Fourier domain (periodic by construction) and
every pattern has an integer number of repeats per tile. Paintings are pictures,
stretched once over a canvas, and need not tile.

Image convention: row 0 is the top of the texture (``v = 1`` in the scene's UVs).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

#: A texture generator: ``(rng, size) -> (size, size, 3) uint8``.
TextureFn = Callable[[np.random.Generator, int], np.ndarray]


# ---------------------------------------------------------------- primitives
def hsv_to_rgb(h: np.ndarray | float, s: np.ndarray | float,
               v: np.ndarray | float) -> np.ndarray:
    """Vectorised HSV → RGB; inputs in [0, 1] broadcast to ``(...)``, output ``(..., 3)``."""
    h, s, v = np.broadcast_arrays(np.asarray(h, float) % 1.0, np.asarray(s, float),
                                  np.asarray(v, float))
    k = (np.array([5.0, 3.0, 1.0]) + h[..., None] * 6.0) % 6.0
    return v[..., None] - v[..., None] * s[..., None] * np.clip(
        np.minimum(k, 4.0 - k), 0.0, 1.0)


def random_color(rng: np.random.Generator, hue: tuple[float, float],
                 sat: tuple[float, float], val: tuple[float, float]) -> np.ndarray:
    """``(3,)`` float RGB in [0, 1] with hue, saturation and value drawn from ranges."""
    return hsv_to_rgb(rng.uniform(*hue), rng.uniform(*sat), rng.uniform(*val))


def periodic_noise(rng: np.random.Generator, size: int,
                   scale: float | tuple[float, float]) -> np.ndarray:
    """``(size, size)`` smooth noise in [0, 1] that tiles seamlessly.

    Args:
        rng: Random generator.
        size: Side in pixels.
        scale: Feature size in pixels; a pair ``(along_u, along_v)`` gives
            anisotropic noise (wood grain, brushed metal).
    """
    su, sv = (scale, scale) if np.isscalar(scale) else scale  # type: ignore[misc]
    f = np.fft.fftfreq(size)
    fv, fu = np.meshgrid(f, f, indexing="ij")
    gain = np.exp(-2.0 * np.pi**2 * ((fu * su) ** 2 + (fv * sv) ** 2))
    field = np.fft.ifft2(np.fft.fft2(rng.standard_normal((size, size))) * gain).real
    lo, hi = field.min(), field.max()
    return (field - lo) / (hi - lo + 1e-12)


def uv_grid(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Pixel-centre coordinates ``(u, v)``, each ``(size, size)`` in [0, 1); v grows upwards."""
    t = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(t, t[::-1])
    return u, v


def mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Blend colours ``a`` and ``b`` (``(3,)`` or ``(S, S, 3)``) by weights ``t`` ``(S, S)``."""
    return a + (b - a) * np.asarray(t)[..., None]


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Float image in [0, 1] → uint8, clipped."""
    return np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)


def _shade(image: np.ndarray, noise: np.ndarray, amount: float) -> np.ndarray:
    """Multiply ``(S, S, 3)`` by ``1 ± amount`` following ``(S, S)`` noise in [0, 1]."""
    return image * (1.0 + amount * (noise[..., None] - 0.5) * 2.0)


def _grout(frac_u: np.ndarray, frac_v: np.ndarray, width: float) -> np.ndarray:
    """``(S, S)`` bool: within ``width`` (in cell units) of a cell border."""
    return (np.minimum(frac_u, 1 - frac_u) < width / 2) | (
        np.minimum(frac_v, 1 - frac_v) < width / 2)


# ------------------------------------------------------------------ surfaces
def plaster(rng: np.random.Generator, size: int) -> np.ndarray:
    """Painted plaster: a pale colour with soft mottling."""
    base = random_color(rng, (0.0, 1.0), (0.03, 0.3), (0.72, 0.95))
    img = _shade(np.broadcast_to(base, (size, size, 3)), periodic_noise(rng, size, 4.0), 0.05)
    return to_uint8(_shade(img, periodic_noise(rng, size, 0.7), 0.03))


def wood(rng: np.random.Generator, size: int) -> np.ndarray:
    """Wood grain running along u (furniture, frames)."""
    return _wood(rng, size, planks=1)


def wood_floor(rng: np.random.Generator, size: int) -> np.ndarray:
    """Wooden floor boards: 4–8 planks per tile with seams and staggered end joints."""
    return _wood(rng, size, planks=int(rng.choice([4, 6, 8])))


def _wood(rng: np.random.Generator, size: int, planks: int) -> np.ndarray:
    u, v = uv_grid(size)
    light = random_color(rng, (0.05, 0.11), (0.35, 0.7), (0.45, 0.88))
    dark = light * rng.uniform(0.45, 0.7)
    row = np.minimum((v * planks).astype(int), planks - 1)
    offset, tone = rng.uniform(0, 1, planks), rng.uniform(0.85, 1.12, planks)
    warp = periodic_noise(rng, size, (size / 3, size / 12))
    rings = (int(rng.integers(3, 7)) * (v + offset[row]) + 0.7 * warp) % 1.0
    img = mix(light, dark, 0.7 * rings**3) * tone[row][..., None]
    img = _shade(img, periodic_noise(rng, size, (size / 6, 0.6)), 0.12)
    if planks > 1:
        joint = rng.uniform(0, 1, planks)[row]
        fu, fv = (u - joint) % 1.0, (v * planks) % 1.0
        seam = (np.minimum(fu, 1 - fu) < 0.8 / size) | (
            np.minimum(fv, 1 - fv) < 0.8 * planks / size)
        img[seam] *= 0.55
    return to_uint8(img)


def tiles(rng: np.random.Generator, size: int) -> np.ndarray:
    """Ceramic tiles with grout: plain, jittered or checkerboard, 2–4 per tile."""
    u, v = uv_grid(size)
    n = int(rng.choice([2, 4]))
    a = random_color(rng, (0.0, 1.0), (0.0, 0.45), (0.5, 0.97))
    b = random_color(rng, (0.0, 1.0), (0.0, 0.5), (0.15, 0.9))
    iu, iv = (u * n).astype(int), (v * n).astype(int)
    if rng.random() < 0.4:
        img = np.where(((iu + iv) % 2 == 0)[..., None], a, b)
    else:
        jitter = rng.uniform(0.9, 1.08, (n, n))
        img = a * jitter[iv, iu][..., None]
    img = _shade(img, periodic_noise(rng, size, 1.5), 0.05)
    grout = _grout((u * n) % 1.0, (v * n) % 1.0, 2.2 * n / size)
    img[grout] = random_color(rng, (0.0, 1.0), (0.0, 0.1), (0.35, 0.85))
    return to_uint8(img)


def carpet(rng: np.random.Generator, size: int) -> np.ndarray:
    """Soft carpet: one saturated colour with fine pile and cloudy variation."""
    base = random_color(rng, (0.0, 1.0), (0.2, 0.65), (0.3, 0.75))
    img = _shade(np.broadcast_to(base, (size, size, 3)), periodic_noise(rng, size, 0.6), 0.22)
    return to_uint8(_shade(img, periodic_noise(rng, size, size / 6), 0.15))


def fabric(rng: np.random.Generator, size: int) -> np.ndarray:
    """Woven upholstery: a small criss-cross weave over one colour."""
    u, v = uv_grid(size)
    base = random_color(rng, (0.0, 1.0), (0.15, 0.7), (0.25, 0.8))
    k = size // 4
    weave = 0.5 + 0.25 * (np.sin(2 * np.pi * k * u) + np.sin(2 * np.pi * k * v))
    return to_uint8(_shade(_shade(np.broadcast_to(base, (size, size, 3)), weave, 0.1),
                           periodic_noise(rng, size, 0.8), 0.1))


def marble(rng: np.random.Generator, size: int) -> np.ndarray:
    """Stone with veins (counter tops, bathroom walls)."""
    u, _ = uv_grid(size)
    base = random_color(rng, (0.0, 1.0), (0.0, 0.15), (0.55, 0.95))
    vein = random_color(rng, (0.0, 1.0), (0.0, 0.3), (0.1, 0.5))
    turb = periodic_noise(rng, size, size / 8) + 0.5 * periodic_noise(rng, size, size / 20)
    t = np.abs(np.sin(np.pi * (2 * u + 3.0 * turb))) ** 0.3
    return to_uint8(mix(vein, base, 0.25 + 0.75 * t))


def brick(rng: np.random.Generator, size: int) -> np.ndarray:
    """Running-bond brick: 8 courses, 4 bricks a course, per-brick colour."""
    u, v = uv_grid(size)
    rows, cols = 8, 4
    iv = (v * rows).astype(int)
    shifted = u * cols + 0.5 * (iv % 2)
    iu = shifted.astype(int) % cols
    base = random_color(rng, (0.0, 0.08), (0.45, 0.75), (0.4, 0.7))
    tone = rng.uniform(0.8, 1.15, (rows, cols))
    img = _shade(base * tone[iv, iu][..., None], periodic_noise(rng, size, 1.0), 0.12)
    img[_grout(shifted % 1.0, (v * rows) % 1.0, 1.5 * rows / size)] = (
        random_color(rng, (0.0, 1.0), (0.0, 0.1), (0.55, 0.8)))
    return to_uint8(img)


# ---------------------------------------------------------------- wallpapers
def _two_tones(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    ground = random_color(rng, (0.0, 1.0), (0.05, 0.5), (0.55, 0.95))
    hue = rng.uniform(0, 1)
    ink = hsv_to_rgb(hue, rng.uniform(0.2, 0.7), rng.uniform(0.2, 0.75))
    return ground, ink


def stripes(rng: np.random.Generator, size: int) -> np.ndarray:
    """Vertical stripes of 2–3 colours with an occasional pin stripe."""
    u, _ = uv_grid(size)
    ground, ink = _two_tones(rng)
    third = random_color(rng, (0.0, 1.0), (0.1, 0.6), (0.4, 0.9))
    k = int(rng.choice([4, 6, 8]))
    phase = (u * k) % 1.0
    cut = np.sort(rng.uniform(0.15, 0.85, 2))
    img = np.where((phase < cut[0])[..., None], ground,
                   np.where((phase < cut[1])[..., None], ink, third))
    img = np.asarray(img, dtype=float)
    if rng.random() < 0.5:
        img[np.abs(phase - 0.5 * cut[0]) < 0.5 * k / size] = ink * 0.7
    return to_uint8(_shade(img, periodic_noise(rng, size, 2.0), 0.04))


def dots(rng: np.random.Generator, size: int) -> np.ndarray:
    """Polka dots on a staggered grid."""
    u, v = uv_grid(size)
    ground, ink = _two_tones(rng)
    n = int(rng.choice([4, 6, 8]))
    iv = (v * n).astype(int)
    du = (u * n + 0.5 * (iv % 2)) % 1.0 - 0.5
    dv = (v * n) % 1.0 - 0.5
    inside = du**2 + dv**2 < rng.uniform(0.12, 0.32) ** 2
    return to_uint8(_shade(mix(ground, ink, inside), periodic_noise(rng, size, 2.0), 0.04))


def damask(rng: np.random.Generator, size: int) -> np.ndarray:
    """Damask-like ornament: a mirror-symmetric motif on a staggered grid."""
    u, v = uv_grid(size)
    ground, ink = _two_tones(rng)
    n = int(rng.choice([2, 3, 4]))
    iv = (v * n).astype(int)
    x = np.abs(2 * ((u * n + 0.5 * (iv % 2)) % 1.0) - 1)  # mirror symmetric in [0, 1]
    y = 2 * ((v * n) % 1.0) - 1
    a, b, c = rng.integers(1, 4, 3)
    motif = (np.cos(np.pi * a * x) * np.cos(np.pi * b * y)
             + 0.8 * np.cos(np.pi * c * (x + np.abs(y))) - 0.5 * (x**2 + y**2))
    t = np.clip((motif - rng.uniform(-0.3, 0.2)) * 3.0, 0.0, 1.0)
    return to_uint8(mix(ground, ink, rng.uniform(0.5, 0.9) * t))


def checks(rng: np.random.Generator, size: int) -> np.ndarray:
    """Plaid / tartan checks: crossing bands of two colours."""
    u, v = uv_grid(size)
    ground, ink = _two_tones(rng)
    second = random_color(rng, (0.0, 1.0), (0.3, 0.8), (0.3, 0.8))
    k = int(rng.choice([2, 4, 8]))
    w = rng.uniform(0.2, 0.45)
    band_u, band_v = (u * k) % 1.0 < w, (v * k) % 1.0 < w
    img = mix(ground, ink, 0.55 * band_u + 0.55 * band_v)
    thin = np.abs((u * k) % 1.0 - 0.75) < 0.6 * k / size
    img[thin] = second
    return to_uint8(img)


# ----------------------------------------------------------------- paintings
def _palette(rng: np.random.Generator, count: int) -> np.ndarray:
    """``(count, 3)`` harmonious colours: hues around a base, varied value."""
    hues = rng.uniform(0, 1) + rng.choice([0.0, 0.08, 0.33, 0.5, 0.6], count)
    return hsv_to_rgb(hues, rng.uniform(0.35, 0.95, count), rng.uniform(0.25, 0.98, count))


def abstract_painting(rng: np.random.Generator, size: int) -> np.ndarray:
    """An abstract composition of rectangles, discs and diagonal bands."""
    u, v = uv_grid(size)
    colors = _palette(rng, 5)
    img = np.broadcast_to(colors[0], (size, size, 3)).copy()
    for k in range(int(rng.integers(5, 12))):
        cx, cy, w, h = rng.uniform(0, 1), rng.uniform(0, 1), *rng.uniform(0.08, 0.5, 2)
        kind = rng.integers(0, 3)
        if kind == 0:
            mask = (np.abs(u - cx) < w / 2) & (np.abs(v - cy) < h / 2)
        elif kind == 1:
            mask = (u - cx) ** 2 + (v - cy) ** 2 < (w / 2) ** 2
        else:
            mask = np.abs((u - cx) + rng.uniform(-1.5, 1.5) * (v - cy)) < w / 6
        img[mask] = colors[1 + k % 4]
    return to_uint8(_shade(img, periodic_noise(rng, size, 1.0), 0.08))


def landscape_painting(rng: np.random.Generator, size: int) -> np.ndarray:
    """A landscape: sky gradient, a sun, layered hills and a foreground."""
    u, v = uv_grid(size)
    top = random_color(rng, (0.5, 0.7), (0.3, 0.8), (0.5, 1.0))
    horizon = random_color(rng, (0.0, 0.17), (0.2, 0.7), (0.7, 1.0))
    img = mix(horizon, top, np.clip((v - 0.3) / 0.7, 0, 1))
    sx, sy = rng.uniform(0.15, 0.85), rng.uniform(0.6, 0.9)
    img[(u - sx) ** 2 + (v - sy) ** 2 < rng.uniform(0.04, 0.1) ** 2] = hsv_to_rgb(
        rng.uniform(0.0, 0.15), 0.6, 1.0)
    ground_hue = rng.uniform(0.15, 0.45)
    layers = int(rng.integers(2, 5))
    for i in range(layers):
        freq = rng.integers(1, 5, 3)
        amp = rng.uniform(0.02, 0.12, 3)
        ridge = 0.65 - 0.45 * i / layers + np.sum(
            amp[:, None, None] * np.sin(2 * np.pi * freq[:, None, None] * u[None]
                                        + rng.uniform(0, 6.3, 3)[:, None, None]), axis=0)
        shade = hsv_to_rgb(ground_hue + 0.03 * i, 0.3 + 0.15 * i, 0.35 + 0.12 * i)
        img[v < ridge] = shade
    return to_uint8(_shade(img, periodic_noise(rng, size, 1.0), 0.06))


def painting(rng: np.random.Generator, size: int) -> np.ndarray:
    """A random painting: abstract or landscape."""
    style = abstract_painting if rng.random() < 0.5 else landscape_painting
    return style(rng, size)


#: Wallpapers a room's walls may get.
WALLPAPERS: tuple[TextureFn, ...] = (stripes, dots, damask, checks)


def book_spines(rng: np.random.Generator, size: int) -> np.ndarray:
    """A row of book spines of random widths and colours with title bands (for shelves)."""
    u, v = uv_grid(size)
    edges = np.cumsum(rng.uniform(0.03, 0.08, 40))
    edges = edges[edges < 1.0]
    book = np.searchsorted(edges, u[0])  # (S,) book index per column
    colors = _palette(rng, len(edges) + 1)
    img = colors[book][None].repeat(size, axis=0)
    band = rng.uniform(0.2, 0.8, len(edges) + 1)[book][None]
    img[np.abs(v - band) < 0.06] *= 0.4
    gap = np.abs(u[0][:, None] - edges[None]).min(axis=1) < 0.6 / size
    img[:, gap] *= 0.5
    return to_uint8(img)
