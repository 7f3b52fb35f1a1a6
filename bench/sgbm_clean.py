"""StereoSGBM on clean scenes, the sanity check of docs/TRAINER.md: no ambient light, no extra lights,
sensor noise off. GigaDepth's Table 2 gives SGM about 10 % outliers on its synthetic data; on clean
renders of ours SGBM's o(1) on lit pixels should come close, and where it does not the split below
says where the outliers are.

    python -m bench.sgbm_clean [--config structure_core] [--scale 0.5] [--scenes 3] \
        [--out out/sgbm_clean]

Renders `--scenes` test-split scenes of the config with world_strength 0, no extra lights, shot and
read noise 0 (the 10-bit quantisation stays) into --out (resumed if already there), then scores SGBM
(plain and LCN, its disparity range sized to the nearest depth, trainer.evaluate) on the lit pixels
(visibility = 1, finite GT): o(0.5..5) overall, per depth range, on and off the edge mask, solvable or
not (dotsim/solvable.py), by the dots' 5 x 5 contrast, and how many of the outliers are pixels SGBM
left without an estimate.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

from dotsim.config_schema import read_toml
from dotsim.configs import config_path, relative_base
from dotsim.dataset import read_frame
from dotsim.frame_source import open_source
from dotsim.solvable import solvable_pixels
from generator.config import config_from_dict
from generator.driver import generate
from trainer.evaluate import load_reference, sgbm_nearest_depth
from trainer.metrics import THRESHOLDS, outlier_counts, outlier_rate, valid_pixels
from trainer.scoring import pixel_classes
from trainer.sgbm import PREPROCESSINGS, num_disparities_for, sgbm_disparity

CLEAN = {"lighting": {"world_strength": [0.0, 0.0], "extra_lights": [0, 0]},
         "sensor": {"shot_noise": 0.0, "read_noise": 0.0}}


# Below this many quantisation steps of local contrast (max - min of the IR over 5 x 5 px) a lit
# pixel's dots are barely in the image: with the noise off the visibility mask's margin (sigmas of
# noise) is zero, so such pixels count as visible though 10 bits hold nothing of their dots.
FAINT_LSB = 4


def dot_contrast(ir: np.ndarray) -> np.ndarray:
    """max - min of the IR image over each pixel's 5 x 5 neighbourhood."""
    ir = np.asarray(ir, np.float32)
    kernel = np.ones((5, 5), np.uint8)
    return cv2.dilate(ir, kernel) - cv2.erode(ir, kernel)


def clean_config(path: Path, scale: float):
    """The config at `path` at render scale `scale` with ambient light, extra lights and noise off."""
    data = read_toml(path)
    for table, values in CLEAN.items():
        data.setdefault(table, {}).update(values)
    data.setdefault("rig", {})["scale"] = scale
    return config_from_dict(data, f"{path} (clean)", base_dir=relative_base(path))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=config_path, default=config_path("structure_core"),
                        help="generator config: a built-in name or a TOML file (default structure_core)")
    parser.add_argument("--scale", type=float, default=0.5, help="render scale (0.5: 608 x 448)")
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=5)
    parser.add_argument("--out", type=Path, default=Path("out/sgbm_clean"))
    args = parser.parse_args(argv)

    summary = generate(clean_config(args.config, args.scale), args.out, "test", args.scenes, seed=args.seed,
                       progress=True)
    print(summary.line())
    source = open_source(args.out, "test")
    frames, rig = source.frames, source.rig
    reference = load_reference(source)
    bits = read_toml(args.config).get("sensor", {}).get("bit_depth", 10)
    nearest = sgbm_nearest_depth(frames, rig)
    n_disp = num_disparities_for(rig, nearest)
    pattern = source.pattern
    rows: dict[tuple[str, str], np.ndarray] = {}
    missing = dict.fromkeys(PREPROCESSINGS, 0)
    for ref in frames:
        f = read_frame(ref.path, channels=("ir", "visibility", "edge", "depth", "disparity"))
        lit, gt = valid_pixels(f["visibility"], f["disparity"]), f["disparity"].astype(np.float64)
        selections = pixel_classes(lit, f["depth"], f["edge"],
                                   solvable_pixels(f["ir"], f["depth"], rig, pattern, ref.scene_meta()))
        faint = dot_contrast(f["ir"]) < FAINT_LSB / 2**bits
        selections[f"contrast < {FAINT_LSB} LSB"] = lit & faint
        selections[f"contrast >= {FAINT_LSB} LSB"] = lit & ~faint
        for p in PREPROCESSINGS:
            pred = sgbm_disparity(f["ir"].astype(np.float32), reference, n_disp, preprocessing=p)
            missing[p] += int((lit & ~np.isfinite(pred)).sum())
            for r, sel in selections.items():
                pixels, over = outlier_counts(pred, gt, sel)
                rows[(p, r)] = rows.get((p, r), 0) + np.array([pixels, *over])
    print(f"{len(frames)} clean frame(s) at {rig.camera.width}x{rig.camera.height}; SGBM with {n_disp} "
          f"disparities (nearest depth {nearest:.3g} m); lit pixels = visibility 1 with finite GT\n")
    print("| SGBM | pixels | " + " | ".join(f"o({t:g})" for t in THRESHOLDS) + " |")
    print("|" + "---|" * (2 + len(THRESHOLDS)))
    for (p, r), c in rows.items():
        rates = " | ".join(f"{outlier_rate(int(v), int(c[0])):.4f}" if c[0] else "-" for v in c[1:])
        print(f"| {p}, {r} | {c[0]} | {rates} |")
    total = rows[(PREPROCESSINGS[0], "all")][0]
    for p in PREPROCESSINGS:
        share = outlier_rate(missing[p], int(total))
        print(f"{p}: {missing[p]} lit pixel(s) without an estimate ({share:.2%} of lit)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
