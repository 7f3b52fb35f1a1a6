"""How closely `dotsim capture fit-sensor` recovers a known sensor: still scenes rendered twice, once
with the known [sensor] (the "capture") and once with the defaults (the rendering it is compared with),
then the fit of the first against the second, parameter by parameter (accuracy, not speed). The
scenes and the known sensor: capture/still_scenes.py.

    python -m bench.sensor_fit [--scale 1.0] [--scenes 2] [--samples 4] [--threads 1] [--out DIR]

Still scenes: an empty room of flat untextured walls ([scene] object_count = [0, 0]), no motion
between a scene's 4 frames (each frame its own sensor noise), no extra light, a pattern the camera
resolves (density 0.003, min spacing 6 projector px: the default one's dots merge at the camera's
resolution, docs/CAPTURE.md), auto exposure to 0.3 (no dot saturates), on the structure_core config
at --scale. tests/capture/test_sensor_fit.py runs the same at scale 0.2.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from capture.still_scenes import KNOWN, render_pair

CHECKED = ("read_noise", "shot_noise", "blur_sigma", "speckle_contrast")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.sensor_fit", description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", type=float, default=1.0, help="[rig] scale (default 1: 1216 x 896)")
    parser.add_argument("--scenes", type=int, default=2, help="still scenes of 4 frames each (default 2)")
    parser.add_argument("--samples", type=int, default=4, help="Cycles samples (default 4)")
    parser.add_argument("--threads", type=int, default=1, help="render threads (default 1; 0: all cores)")
    parser.add_argument("--out", type=Path, help="keep the renderings here (default: a temporary folder); "
                        "a rerun with the same folder fits them again without rendering")
    args = parser.parse_args(argv)

    from capture.sensor_fit import fit, measure
    from capture.static_recording import open_recording
    from generator.config import load_config

    with tempfile.TemporaryDirectory(prefix="dotsim-sensor-fit-") as tmp:
        folder = args.out or Path(tmp)
        start = time.perf_counter()
        paths = render_pair(load_config("structure_core"), folder, args.scale, args.scenes, KNOWN,
                            render={"samples": args.samples, "threads": args.threads})
        rendered = time.perf_counter()
        capture = measure(open_recording([str(paths["capture"])]))
        reference = measure(open_recording([str(paths["reference"])]))
        fitted = fit(capture, reference, KNOWN["speckle_grain"])
        done = time.perf_counter()
    width, height = capture.recording.size
    print(f"structure_core at scale {args.scale:g} ({width} x {height}), {args.scenes} still scenes of 4 "
          f"frames, {args.samples} samples: {capture.dots} isolated dots measured in the capture, "
          f"{reference.dots} in the rendering")
    print(f"{'parameter':18}{'known':>10}{'fitted':>12}{'error':>10}{'off by':>10}")
    worst = 0.0
    for key in CHECKED:
        off = fitted.values[key] / KNOWN[key] - 1
        worst = max(worst, abs(off))
        print(f"{key:18}{KNOWN[key]:>10g}{fitted.values[key]:>12g}{fitted.errors[key]:>10.2g}"
              f"{100 * off:>9.1f}%")
    print(f"worst {100 * worst:.1f}% (goal: within 10%); rendering {rendered - start:.0f} s, fit "
          f"{done - rendered:.0f} s")
    return 0 if worst <= 0.1 else 1


if __name__ == "__main__":
    raise SystemExit(main())
