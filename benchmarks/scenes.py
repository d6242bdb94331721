"""Scene building speed: procedural apartments, real-mesh import, cached reloads.

Targets (issue): procedural scene with navigation + geodesic cache < 2 s; the 145K-
triangle house imported < 10 s; cached reload < 0.5 s. Prints medians of repeats.

    python benchmarks/scenes.py
"""

from __future__ import annotations

import statistics
import tempfile
import time
from pathlib import Path

from collavn.scenes import load_scene
from collavn.scenes.summary import largest_geodesic

HOUSE = Path(__file__).resolve().parents[2] / "shared" / "scenes" / "aws_small_house.glb"


def timed(fn, repeats: int = 3) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for seed in (0, 3, 11):
            spec = f"procedural:{seed}"
            build = timed(lambda spec=spec: largest_geodesic(load_scene(spec, cache=False)))
            load_scene(spec, cache_dir=tmp)
            reload = timed(lambda spec=spec: load_scene(spec, cache_dir=tmp))
            scene = load_scene(spec, cache_dir=tmp)
            print(f"{spec:<16} {scene.num_triangles:>7} tris  build+nav+2 geodesic fields "
                  f"{build:6.2f} s (target < 2)   cached reload {reload:5.2f} s (target < 0.5)")
        if not HOUSE.is_file():
            print(f"skipped: {HOUSE} not present")
            return
        spec = str(HOUSE)
        build = timed(lambda: load_scene(spec, cache=False), repeats=2)
        load_scene(spec, cache_dir=tmp)
        reload = timed(lambda: load_scene(spec, cache_dir=tmp))
        print(f"{HOUSE.name:<16} {load_scene(spec, cache_dir=tmp).num_triangles:>7} tris  "
              f"import+nav {build:6.2f} s (target < 10)   cached reload {reload:5.2f} s "
              f"(target < 0.5)")


if __name__ == "__main__":
    main()
