"""Benchmark: dot-pattern generation time and row-window uniqueness versus density.

    python -m bench.pattern_uniqueness [--repeats 3] [--rig structure_core]

Part 1 times generate_dot_pattern at the rig's projector resolution (3072 x 3072 for Structure Core)
for several dot counts: median of --repeats runs, and the time relative to the 40k-dot case.
Part 2 reports, per density, the share of unique row windows (best NCC < 0.9 against every window
within the disparity range) for 5, 7, 9 and 11 camera-px windows searched over 128 camera px,
converted to pattern px with the rig's projector/camera focal ratio, on a 1024 x 1024 crop-sized
pattern (uniqueness is a local property; the full size only costs time).
"""

from __future__ import annotations

import argparse
import statistics
import time

from dotsim.patterns import DEFAULT_DENSITY, generate_dot_pattern, row_window_uniqueness
from dotsim.rig.presets import DEFAULT_PRESET, PRESETS, get_preset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per case (median reported)")
    parser.add_argument("--rig", default=DEFAULT_PRESET, choices=sorted(PRESETS))
    args = parser.parse_args()
    rig = get_preset(args.rig)
    width, height = rig.projector.width, rig.projector.height
    pixels = width * height

    print(f"generate_dot_pattern {width}x{height}, min_spacing 3, sigma 0.8, median of {args.repeats} runs")
    reference_time = None
    for n_dots in (40_000, round(0.01 * pixels), round(DEFAULT_DENSITY * pixels), round(0.04 * pixels)):
        times = []
        for seed in range(args.repeats):
            start = time.perf_counter()
            generate_dot_pattern(width, height, n_dots=n_dots, seed=seed)
            times.append(time.perf_counter() - start)
        median = statistics.median(times)
        reference_time = reference_time or median
        print(f"  {n_dots:>7d} dots ({n_dots / pixels:.4f}/px): {median:6.2f} s  "
              f"x{median / reference_time:.2f} vs 40k")

    ratio = rig.projector.fx / rig.camera.fx
    camera_windows = (5, 7, 9, 11)
    search = round(128 * ratio)
    print(f"row-window uniqueness (share of windows with best NCC < 0.9 within +-128 camera px = "
          f"{search} pattern px; windows in camera px, x{ratio:.2f} in pattern px)")
    print("  density/px  " + "  ".join(f"{w:>2d}x{w:<2d}" for w in camera_windows) + "  (camera px)")
    for density in (0.005, 0.01, DEFAULT_DENSITY, 0.04):
        pattern = generate_dot_pattern(1024, 1024, density=density, seed=0)
        shares = [row_window_uniqueness(pattern.image, window=round(w * ratio) | 1, search=search)
                  ["unique_share"] for w in camera_windows]
        print(f"  {density:10.3f}  " + "  ".join(f"{100 * s:5.1f}" for s in shares)
              + ("  <- default" if density == DEFAULT_DENSITY else ""))
    print("done: pattern generation and uniqueness measured")


if __name__ == "__main__":
    main()
