"""Renderer throughput: textured panoramas/s (RGB + depth) vs the raw Embree cast rate.

    python benchmarks/render.py [--batch 64] [--reps 7] [--no-warp] [--threads 2]

For each scene (a procedural apartment, and ``../shared/scenes/aws_small_house.glb``
when present) and each panorama size, prints the median over ``--reps`` batches of:
the end-to-end Embree renderer, the raw Embree cast of exactly the same rays (primitive
ids only, same threads and chunks, rays prepared in advance), their ratio, and the
Warp backend on the CPU.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from embreex import mesh_construction, rtcore_scene

from collavn.rendering import CameraSpec, Renderer
from collavn.rendering.shading import fill_rays
from collavn.scenes.builder import SceneBuilder, flat_texture
from collavn.scenes.scene import Scene

SIZES = ((512, 128), (256, 64), (128, 32))
HOUSE = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "aws_small_house.glb"


def apartment() -> Scene:
    """Procedural apartment 0; a hand-built multi-room flat if that is unavailable."""
    try:
        from collavn.scenes.procedural import generate_apartment

        return generate_apartment(0)
    except Exception as e:  # the generator is optional for this benchmark
        print(f"(procedural apartment unavailable: {e}; using a hand-built flat)")
    b = SceneBuilder(64)
    rng = np.random.default_rng(0)
    mats = [b.material(f"m{k}", rng.integers(0, 255, (64, 64, 3), dtype=np.uint8))
            for k in range(8)]
    b.add_box((0, 0, -0.1), (12, 9, 0), mats[0])
    b.add_box((0, 0, 2.5), (12, 9, 2.6), b.material("ceiling", flat_texture((240,) * 3, 64)))
    for x in (0, 4, 8, 12):
        b.add_box((x - 0.05, 0, 0), (x + 0.05, 3.5, 2.5), mats[1])
        b.add_box((x - 0.05, 4.5, 0), (x + 0.05, 9, 2.5), mats[2])
    for y in (0, 9):
        b.add_box((0, y - 0.05, 0), (12, y + 0.05, 2.5), mats[3])
    for k in range(60):
        b.add_cylinder(rng.uniform(0.5, 11.5, 2), 0.04, 0.0, 0.75, mats[4 + k % 4], segments=8)
    return b.build("hand-built flat")


def random_poses(scene: Scene, n: int, seed: int = 0) -> np.ndarray:
    """``(n, 3)`` poses on navigable cells of the largest region, random yaw."""
    rng = np.random.default_rng(seed)
    rows, cols = np.nonzero(scene.nav.components == 1)
    k = rng.integers(0, len(rows), n)
    xy = scene.nav.cell_centers(rows[k], cols[k])
    return np.column_stack([xy, rng.uniform(-np.pi, np.pi, n)])


def median_rate(fn: Callable[[], object], batch: int, reps: int) -> float:
    """Views per second: the median over ``reps`` timed calls after one warm-up."""
    fn()
    times = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return batch / float(np.median(times))


def raw_cast(scene: Scene, spec: CameraSpec, poses: np.ndarray, threads: int,
             chunk: int) -> Callable[[], object]:
    """A callable casting the renderer's rays with Embree and nothing else."""
    embree = rtcore_scene.EmbreeScene()
    mesh = mesh_construction.TriangleMesh(embree, scene.vertices, scene.faces)
    views = np.column_stack([poses[:, :2], np.full(len(poses), scene.floor_z + 0.9),
                             np.cos(poses[:, 2]), np.sin(poses[:, 2])]).astype(np.float32)
    cam = spec.ray_directions()
    total = len(poses) * len(cam)
    origins, dirs = np.empty((total, 3), np.float32), np.empty((total, 3), np.float32)
    fill_rays(cam, views, 0, origins, dirs)
    chunks = [(g, min(g + chunk, total)) for g in range(0, total, chunk)]
    pool = ThreadPoolExecutor(threads)

    def work(part: list[tuple[int, int]]) -> None:
        for g0, g1 in part:
            embree.run(origins[g0:g1], dirs[g0:g1])

    def cast() -> object:
        _ = mesh  # keep the geometry alive with the scene
        return [f.result() for f in [pool.submit(work, chunks[k::threads])
                                     for k in range(threads)]]

    return cast


def bench_scene(scene: Scene, args: argparse.Namespace) -> None:
    print(f"\n{scene.name}: {scene.num_triangles} triangles, {len(scene.textures)} textures, "
          f"batch {args.batch}, {args.threads} threads")
    print(f"{'size':>8} {'render/s':>9} {'cast/s':>8} {'ratio':>6} {'warp-cpu/s':>11}")
    poses = random_poses(scene, args.batch)
    for w, h in SIZES:
        spec = CameraSpec.panorama(w, h)
        with Renderer(scene, panorama=spec, threads=args.threads) as r:
            rate = median_rate(lambda r=r: r.render(poses), args.batch, args.reps)
        cast = median_rate(raw_cast(scene, spec, poses, args.threads, 16384), args.batch,
                           args.reps)
        warp = "-"
        if not args.no_warp:
            wr = Renderer(scene, backend="warp", panorama=spec)
            warp = f"{median_rate(lambda wr=wr: wr.render(poses), args.batch, 3):.0f}"
        print(f"{w}x{h:<4} {rate:9.0f} {cast:8.0f} {rate / cast:6.2f} {warp:>11}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--batch", type=int, default=64)
    parser.add_argument("--reps", type=int, default=7)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--no-warp", action="store_true", help="skip the Warp CPU backend")
    args = parser.parse_args()
    bench_scene(apartment(), args)
    if not HOUSE.is_file():
        print(f"\nskipping the real house: {HOUSE} not found")
        return
    try:
        from collavn.scenes import load_scene

        house = load_scene(str(HOUSE))
    except Exception as e:  # the mesh loader is someone else's module
        print(f"\nskipping the real house: cannot load {HOUSE}: {e}")
        return
    bench_scene(house, args)


if __name__ == "__main__":
    main()
