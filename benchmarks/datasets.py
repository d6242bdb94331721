"""Episode generation speed per scene, cold and once the geodesic fields are cached.

    python benchmarks/datasets.py                      # procedural:0 and a built scene
    python benchmarks/datasets.py --scenes procedural:3 path/to/mesh.glb

"Cold" includes one fast-marching run per goal; "warm" repeats the same seed so
every goal's field comes from ``Scene``'s in-memory cache (≤ 256 fields, hence the
modest episode counts), which isolates the sampling itself.
"""

from __future__ import annotations

import argparse
import time

from collavn.datasets.generator import Preset, episode_rng, generate_split
from collavn.scenes.builder import SceneBuilder, flat_texture
from collavn.scenes.scene import Scene

CASES = [("commongoal", 2), ("commongoal", 4), ("specificgoal", 2), ("specificgoal", 4)]


def built_scene() -> Scene:
    """A 12 × 10 m floor with four rooms joined by doors (no procedural code needed)."""
    b = SceneBuilder(texture_size=8)
    m = b.material("w", flat_texture((200, 200, 200), 8))
    b.add_box((0, 0, -0.1), (12, 10, 0), m)
    walls = [((0, 0), (12, 0.1)), ((0, 9.9), (12, 10)), ((0, 0), (0.1, 10)),
             ((11.9, 0), (12, 10)), ((6, 0), (6.1, 4)), ((6, 5), (6.1, 10)),
             ((0, 5), (2, 5.1)), ((3, 5), (9, 5.1)), ((10, 5), (12, 5.1))]
    for (x0, y0), (x1, y1) in walls:
        b.add_box((x0, y0, 0), (x1, y1, 2.5), m)
    return b.build("four-rooms")


def measure(scene: Scene, task: str, n: int, per_difficulty: int) -> tuple[float, float]:
    """Episodes/s of one val split: cold, then warm (same seed, cached fields)."""
    preset = Preset("bench", train=0, val=per_difficulty, test=0)
    rates = []
    for _ in range(2):
        rng = episode_rng(0, task, n, "val", scene.name)
        t0 = time.perf_counter()
        episodes = generate_split(scene, task, n, "val", preset, rng)
        rates.append(len(episodes) / (time.perf_counter() - t0))
    return rates[0], rates[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="*", default=["procedural:0"])
    parser.add_argument("--per-difficulty", type=int, default=50)
    args = parser.parse_args()
    scenes = [built_scene()]
    for spec in args.scenes:
        try:
            from collavn.scenes import load_scene

            scenes.append(load_scene(spec))
        except Exception as e:  # a missing optional scene source only skips it
            print(f"skipping {spec}: {e}")
    for scene in scenes:
        print(f"\n{scene.name}: grid {scene.nav.shape}, "
              f"navigable {scene.nav.navigable.sum() * scene.nav.resolution**2:.0f} m²")
        for task, n in CASES:
            scene._fields.clear()
            cold, warm = measure(scene, task, n, args.per_difficulty)
            print(f"  {task:13s} N={n}: {cold:7.0f} episodes/s cold, {warm:7.0f} warm "
                  f"({len(scene._fields)} fields cached)")


if __name__ == "__main__":
    main()
