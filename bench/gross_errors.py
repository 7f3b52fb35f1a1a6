"""Where a trained network's gross errors on near surfaces are: which way they miss, whether they are
edges, patches or lone pixels, and how slanted the surfaces under them are.

    python -m bench.gross_errors --checkpoint out/bench60/run/checkpoint.pt \
        --data data/table2/test_seen [--frames 16] [--near 1.0] [--threshold 5]

On `--frames` frames spread over --data's test split, the valid pixels nearer than --near m whose
disparity is off by more than --threshold px: the share the network puts too far (smaller disparity)
and too near; the share in connected patches of 50 pixels or more; the share more than 20 px from the
edge mask; and the median slope of the GT disparity (px per px, along the rows and down the columns)
under them, off the edge mask, beside that under the near pixels the network gets within 0.5 px. A
slope above trainer.scoring.SLANT marks the pattern stretched or sheared against a plane facing the
camera (trainer.samples.tilted_plane): docs/results/trainer_screens.md reads these figures.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np
import torch
from scipy import ndimage

from dotsim.frame_source import open_source, spread
from dotsim.rig.geometry import disparity_to_depth
from trainer.checkpoint import load_model, predict_disparity
from trainer.metrics import valid_pixels
from trainer.scoring import disparity_slopes

PATCH_PIXELS = 50  # a connected set of wrong pixels this large is a surface's, not a lone miss
FAR_FROM_EDGE_PX = 20


def gross_errors(pred: np.ndarray, frame: dict, rig, near: float, threshold: float) -> dict[str, np.ndarray]:
    """Per-pixel masks and slopes of one frame: `wrong` (valid, nearer than `near`, off by more than
    `threshold`), `right` (valid, nearer, within 0.5 px), `too_far`, `patch`, `far_from_edge`, `on_edge`,
    and the absolute GT disparity slopes `along` and `down`."""
    gt = frame["disparity"].astype(np.float64)
    valid = valid_pixels(frame["visibility"], frame["disparity"])
    with np.errstate(invalid="ignore"):
        near_pixels = valid & (disparity_to_depth(gt, rig) < near)
        err = np.abs(pred - gt)
        wrong = near_pixels & ~(err <= threshold)
        right = near_pixels & (err <= 0.5)
        along, down = disparity_slopes(gt)
    labels, count = ndimage.label(wrong)
    sizes = np.bincount(labels.ravel(), minlength=count + 1)
    edge = frame["edge"] > 0
    return {"wrong": wrong, "right": right, "too_far": wrong & ~(pred >= gt),
            "patch": wrong & (sizes[labels] >= PATCH_PIXELS) & (labels > 0),
            "far_from_edge": wrong & (ndimage.distance_transform_edt(~edge) > FAR_FROM_EDGE_PX),
            "on_edge": edge, "along": along, "down": down}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", required=True)
    parser.add_argument("--data", required=True)
    parser.add_argument("--split", default="test")
    parser.add_argument("--frames", type=int, default=16)
    parser.add_argument("--near", type=float, default=1.0, help="m: the depth below which pixels count")
    parser.add_argument("--threshold", type=float, default=5.0, help="px: a gross error")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    model, _, rig = load_model(args.checkpoint)
    source = open_source(args.data, args.split)
    counts: dict[str, int] = {}
    slopes: dict[str, list[np.ndarray]] = {"wrong": [], "right": []}
    for ref in spread(source.frames, args.frames):
        frame = ref.read(("ir", "disparity", "visibility", "edge"))
        pred = predict_disparity(model, rig, frame["ir"].astype(np.float32))[0]
        masks = gross_errors(pred, frame, rig, args.near, args.threshold)
        for key in ("wrong", "right", "too_far", "patch", "far_from_edge"):
            counts[key] = counts.get(key, 0) + int(masks[key].sum())
        for key in slopes:
            off_edge = masks[key] & ~masks["on_edge"]
            slopes[key].append(np.stack([masks["along"][off_edge], masks["down"][off_edge]]))
    wrong = max(counts["wrong"], 1)
    print(f"{args.frames} frames of {args.data}: {counts['wrong']} valid pixels nearer than {args.near:g} m "
          f"off by more than {args.threshold:g} px, {counts['right']} within 0.5 px")
    print(f"too far: {counts['too_far'] / wrong:.3f}, too near: {1 - counts['too_far'] / wrong:.3f}")
    print(f"in patches of {PATCH_PIXELS} px or more: {counts['patch'] / wrong:.3f}; more than "
          f"{FAR_FROM_EDGE_PX} px from the edge mask: {counts['far_from_edge'] / wrong:.3f}")
    for key, label in (("wrong", "wrong"), ("right", "within 0.5 px")):
        along, down = np.median(np.concatenate(slopes[key], axis=1), axis=1)
        print(f"median GT disparity slope under the {label} pixels off the edge mask: {along:.3f} px per "
              f"column, {down:.3f} px per row")
    return 0


if __name__ == "__main__":
    sys.exit(main())
