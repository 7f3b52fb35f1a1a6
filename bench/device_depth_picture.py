"""The picture of docs/DEVICE_DEPTH.md: a rendered frame's IR, ground-truth depth and device depth side
by side, and how far the device's depth is from the truth.

    python -m bench.device_depth_picture DATASET [--scene 0] [--frame 0] [--out device_depth.png]

DATASET: frames that store device_depth (`dotsim generate` with [device_depth] on, e.g. the
realsense_d415 config). Prints the share of pixels with ground truth (finite, within the rig's
max_depth) that have no device depth, the columns without any, and the error of the rest.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from dotsim.dataset import open_dataset, read_scene_meta
from dotsim.false_colour import colourise, titled
from dotsim.images import write_image
from dotsim.rig.geometry import Rig

PANEL = (320, 180)  # each panel's size in the picture, px


def device_depth_summary(device: np.ndarray, truth: np.ndarray) -> dict:
    """Share of the pixels with ground truth (finite) that have no device depth (NaN), columns without
    any device depth, and the relative error of the rest (median, share above 5 %).

    >>> truth = np.full((2, 4), 2.0)
    >>> device = np.array([[np.nan, 2.0, 2.2, 2.0], [np.nan, 2.0, 2.0, 2.0]])
    >>> device_depth_summary(device, truth)
    {'none': 0.25, 'empty_columns': 1, 'median_error': 0.0, 'over_5_percent': 0.16666666666666666}
    """
    has_truth = np.isfinite(truth)
    both = has_truth & np.isfinite(device)
    error = np.abs(device[both] - truth[both]) / truth[both]
    return {"none": float(1 - both.sum() / has_truth.sum()),
            "empty_columns": int(np.isnan(device).all(0).sum()),
            "median_error": float(np.median(error)), "over_5_percent": float((error > 0.05).mean())}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--scene", type=int, default=0)
    parser.add_argument("--frame", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("device_depth.png"))
    args = parser.parse_args(argv)
    dataset = open_dataset(args.dataset)
    scene = dataset.read_scene(args.scene)
    rig = Rig.from_dict(read_scene_meta(dataset.scenes[args.scene].path)["rig"])
    frame = scene.frames[args.frame]
    truth = np.where(frame["depth"] <= rig.max_depth, frame["depth"], np.nan)
    device = frame["device_depth"]
    summary = device_depth_summary(device, truth)
    print(f"{summary['none']:.1%} of the pixels with ground truth have no device depth; "
          f"{summary['empty_columns']} columns have none; the rest are {summary['median_error']:.2%} off at "
          f"the median, {summary['over_5_percent']:.1%} of them more than 5 % off")
    low, high = np.nanpercentile(truth, 1), np.nanpercentile(truth, 99)
    ir = np.clip(np.sqrt(frame["ir"].astype(np.float32)) * 255, 0, 255).astype(np.uint8)

    def panel(image: np.ndarray, title: str) -> np.ndarray:
        return titled(cv2.resize(image, PANEL, interpolation=cv2.INTER_NEAREST), title, PANEL[0])

    device_title = f"device depth ({summary['none']:.0%} none)"
    picture = np.concatenate([panel(cv2.cvtColor(ir, cv2.COLOR_GRAY2BGR), "IR (left, sqrt)"),
                              panel(colourise(truth, low, high), "ground truth"),
                              panel(colourise(device, low, high), device_title)], axis=1)
    write_image(args.out, picture)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
