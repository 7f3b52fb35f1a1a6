"""Evaluation: outlier rates o(t) of the network and of StereoSGBM on the same frames, error images.

o(t) is the share of valid pixels whose disparity error exceeds t camera pixels at full resolution
(t = 0.5, 1, 2, 5). Valid: the pattern is visible and the GT disparity is finite and positive. A pixel a
method gives no estimate for counts as an outlier, so no method gains by abstaining. The network's
half-resolution output sits on pixels (2i, 2j); it is converted column -> depth -> disparity with
dotsim.rig there and brought to full resolution by interpolation that keeps those samples exactly and
does not blend across depth jumps (upsample_half with DEPTH_JUMP_PX). Rows are split by GT depth range
as well as overall.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import cv2
import numpy as np
import torch
from tqdm import tqdm

from dotsim.data import pattern_file
from dotsim.false_colour import titled, with_legend
from dotsim.file_io import atomic_write_bytes
from dotsim.images import write_image
from dotsim.patterns import PatternError, load_pattern
from dotsim.rig import (
    Rig,
    depth_to_disparity,
    depth_to_projector_column,
    disparity_to_depth,
    projector_column_to_depth,
    reference_image,
)
from trainer.config import Config
from trainer.data import DataError, FrameRef, list_frames
from trainer.model import LOW_PRECISION, GigaDepthNet, autocast
from trainer.sgbm import PREPROCESSINGS, num_disparities_for, sgbm_disparity
from trainer.train import build_model, check_rig, load_checkpoint

THRESHOLDS = (0.5, 1.0, 2.0, 5.0)
PRECISIONS = ("float32", *LOW_PRECISION)  # of inference (`--precision`)
DEPTH_BINS = (0.0, 1.0, 2.0, 4.0, 8.0, 20.0)  # metres; the last bin edge is the rig's training range
EVAL_CHANNELS = ("ir", "visibility", "disparity")  # depth follows from disparity: exports may hold no depth


def outlier_counts(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray,
                   thresholds=THRESHOLDS) -> tuple[int, list[int]]:
    """(valid pixels, [pixels with |pred - gt| > t for t in thresholds]); nan predictions are outliers."""
    err = np.abs(np.asarray(pred, np.float64) - gt)[valid]
    err = np.where(np.isfinite(err), err, np.inf)
    return int(valid.sum()), [int((err > t).sum()) for t in thresholds]


# Neighbouring half-resolution samples further apart than this (camera px of disparity) lie on two
# surfaces: the pixel between them takes the farther one instead of their mean, so no "flying pixels"
# float between a foreground object and its background. Measured with dotsim/configs/train_cpu.toml
# (then with the published backbone) after 41 min (docs/TRAINER.md): o(0.5) 0.395 (linear) -> 0.369
# (nearer sample) -> 0.354 (farther) on the test split, 0.473 -> 0.448 -> 0.435 on 20 unseen
# train-asset scenes; 0.5 and 2 px gave within 0.001.
DEPTH_JUMP_PX = 1.0


def upsample_half(half: np.ndarray, height: int, width: int, jump: float | None = None) -> np.ndarray:
    """(h, w) values at full-res pixels (2i, 2j) -> (height, width), the native samples kept exactly.

    In between: the mean of the two neighbouring samples (linear), or, with `jump`, the smaller of the
    two where they differ by more than `jump` or one is nan (for disparity: the farther surface). The
    odd last row/column (if any) is extrapolated linearly from the two samples before it (copied from
    the last one across a jump). Applied along rows, then columns."""
    def along(a: np.ndarray, n: int, axis: int) -> np.ndarray:
        a = np.moveaxis(a, axis, 0)
        out = np.empty((n, *a.shape[1:]), np.float64)
        out[0::2] = a[: (n + 1) // 2]
        left, right = a[:-1], a[1:]
        inner = (left + right) / 2
        if jump is not None:
            inner = np.where(np.abs(left - right) <= jump, inner, np.fmin(left, right))
        out[1::2][: len(inner)] = inner[: n // 2]
        if n % 2 == 0:  # the last (odd) index has no sample to its right
            last = a[n // 2 - 1]
            if len(a) > 1:
                before = a[n // 2 - 2]
                extrapolated = 1.5 * last - 0.5 * before
                last = extrapolated if jump is None else np.where(np.abs(last - before) <= jump,
                                                                  extrapolated, last)
            out[n - 1] = last
        return np.moveaxis(out, 0, axis)

    return along(along(np.asarray(half, np.float64), height, 0), width, 1)


def load_model(checkpoint: str | Path, device: str = "cpu") -> tuple[GigaDepthNet, Config, Rig]:
    """The trained network of a checkpoint on `device`, in eval mode, with its config and rig.

    The file is read to CPU whatever device wrote it (a CUDA run's checkpoint loads on a machine
    without one), then the network is moved to `device`."""
    ckpt, cfg, rig = load_checkpoint(checkpoint)
    model = build_model(cfg, rig)
    model.load_state_dict(ckpt["model"])
    return model.to(device).eval(), cfg, rig


def predict_disparity(model: GigaDepthNet, rig: Rig, ir: np.ndarray, device: str = "cpu",
                      precision: str = "float32"):
    """(disparity camera px, depth metres), each (H, W) float32, nan where the column gives no depth.

    precision: float32, or float16 / bfloat16 autocast (the column itself is computed in float32)."""
    model.eval()
    with torch.no_grad(), autocast(device, precision):
        x = torch.from_numpy(np.ascontiguousarray(ir, np.float32))[None, None].to(device)
        column = model(x)[0].float().cpu().numpy()
    height, width = rig.camera.height, rig.camera.width
    # Linear upsampling of the column keeps the samples at (2i, 2j) exact, so converting at full size
    # and reading those pixels back gives each sample's disparity at its own pixel.
    full_column = upsample_half(column, height, width)
    disparity = depth_to_disparity(projector_column_to_depth(full_column, rig, normalised=True), rig)
    disparity = upsample_half(disparity[0::2, 0::2], height, width, jump=DEPTH_JUMP_PX)
    return disparity.astype(np.float32), disparity_to_depth(disparity, rig).astype(np.float32)


# Colours of the error images (BGR) and what they mean, for the images and their legends.
OUTLIER_COLOUR = (0, 0, 0)
NO_GT_COLOUR = (128, 128, 128)
ERROR_SWATCHES = ((OUTLIER_COLOUR, "black: error > 5 px, or no estimate (an outlier)"),
                  (NO_GT_COLOUR, "grey: no ground truth (pattern not visible), not scored"))


def error_image(err: np.ndarray, valid: np.ndarray, max_px: float = 5.0) -> np.ndarray:
    """BGR uint8: |error| 0..max_px on the turbo colour map, outliers (> max_px or no estimate)
    black, pixels without ground truth mid grey (as GigaDepth's figures)."""
    err = np.abs(err)
    scaled = np.clip(np.nan_to_num(err, nan=0.0) / max_px * 255, 0, 255).astype(np.uint8)
    img = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    img[~(err <= max_px)] = OUTLIER_COLOUR
    img[~valid] = NO_GT_COLOUR
    return img


# The narrowest panel of an error strip (IR | network | SGBM): smaller frames are scaled up by a whole
# factor (dotsim.false_colour.titled), so that the title over each panel is readable.
PANEL_WIDTH = 240


def load_reference(data, rig: Rig) -> np.ndarray:
    """The data's pattern (DATASET/pattern.png, or an export's) as seen from infinity on the camera grid."""
    path = pattern_file(data)
    try:
        pattern = load_pattern(path, (rig.projector.height, rig.projector.width))
    except PatternError as e:
        raise DataError(f"{e} (SGBM matches against the dataset's projector pattern)") from e
    return reference_image(pattern.image, rig, supersample=4)


def valid_pixels(frame: dict[str, np.ndarray]) -> np.ndarray:
    """Pixels that are scored: the pattern is visible and the GT disparity finite and positive."""
    gt = frame["disparity"]
    return (frame["visibility"] > 0) & np.isfinite(gt) & (gt > 0)


def configured_nearest_depth(ref: FrameRef) -> float | None:
    """The nearest object distance of the config a frame was rendered with ([scene] distance's lower
    bound, from scene.json), or None for data without one (captures, oracle-rendered tests)."""
    distance = ref.scene_meta().get("config", {}).get("scene", {}).get("distance")
    return float(distance[0]) if distance else None


def nearest_valid_depth(frames: list[FrameRef], rig: Rig) -> float:
    """The smallest GT depth over the valid pixels of `frames` (inf when none is valid): the depth of
    the largest GT disparity (exports may store no depth)."""
    largest = 0.0
    for ref in frames:
        f = ref.read(("visibility", "disparity"))
        valid = valid_pixels(f)
        if valid.any():
            largest = max(largest, float(f["disparity"][valid].max()))
    return float(disparity_to_depth(np.float64(largest), rig)) if largest > 0 else np.inf


def sgbm_nearest_depth(frames: list[FrameRef], rig: Rig) -> float:
    """The nearest depth SGBM's range must reach on these frames: the nearer of the config's scene
    distance and the data's nearest valid GT depth, so no valid pixel lies beyond its range."""
    candidates = [nearest_valid_depth(frames, rig)]
    if frames and (configured := configured_nearest_depth(frames[0])) is not None:
        candidates.append(configured)
    nearest = min(candidates)
    if not np.isfinite(nearest):
        raise DataError(f"{frames[0].path if frames else 'no frames'}: no valid pixel (visible "
                        "pattern with finite depth) to size SGBM's disparity range on")
    return nearest


def spread(frames: list, count: int) -> list:
    """`count` items spread evenly over `frames` (all of them when there are fewer)."""
    if count <= 0 or len(frames) <= count:
        return list(frames)
    return [frames[k] for k in np.linspace(0, len(frames) - 1, count).round().astype(int)]


def choose_preprocessing(frames: list[FrameRef], reference: np.ndarray, num_disparities: int
                         ) -> tuple[str, dict[str, float]]:
    """(the SGBM preprocessing with the lower o(0.5) on `frames`, {preprocessing: o(0.5)}).

    `frames` are validation frames (never the evaluated ones): the choice must not see the test."""
    outliers = dict.fromkeys(PREPROCESSINGS, 0)
    pixels = 0
    for ref in frames:
        f = ref.read(EVAL_CHANNELS)
        valid, gt = valid_pixels(f), f["disparity"].astype(np.float64)
        pixels += int(valid.sum())
        for name in PREPROCESSINGS:
            pred = sgbm_disparity(f["ir"].astype(np.float32), reference, num_disparities, preprocessing=name)
            outliers[name] += outlier_counts(pred, gt, valid, thresholds=(0.5,))[1][0]
    rates = {name: outliers[name] / pixels if pixels else float("nan") for name in PREPROCESSINGS}
    return min(PREPROCESSINGS, key=lambda name: (not rates[name] <= 1, rates[name])), rates


# GigaDepth's Table 2 (synthetic Kinect data, 640 x 480): the only published figures on data like ours.
GIGADEPTH_REFERENCE = ("GigaDepth's Table 2 (synthetic Kinect data, 640 x 480): SGM o(0.5) 10.4 %, "
                       "GigaDepth o(0.5) 1.9 % (5.5x fewer outliers)")


def format_table(rows: list[dict]) -> str:
    head = ("| method | depth range (m) | pixels | outside range | "
            + " | ".join(f"o({t:g})" for t in THRESHOLDS) + " |")
    lines = [head, "|" + "---|" * (4 + len(THRESHOLDS))]
    for r in rows:
        rates = " | ".join(f"{r[f'o({t:g})']:.4f}" if r["pixels"] else "-" for t in THRESHOLDS)
        lines.append(f"| {r['method']} | {r['range']} | {r['pixels']} | {r['outside']} | {rates} |")
    return "\n".join(lines) + "\n"


def overall(rows: list[dict], method: str) -> dict:
    """The 'all' depth-range row of a method."""
    return next(r for r in rows if r["method"] == method and r["range"] == "all")


def chosen_sgbm(rows: list[dict]) -> str:
    """The SGBM variant the network is judged against (chosen on validation frames)."""
    return next(r["method"] for r in rows if r["chosen"])


def verdict(rows: list[dict], sgbm_method: str) -> str:
    """One line: the network against the chosen SGBM at o(0.5) and o(2), and GigaDepth's ratio."""
    net, sgbm = overall(rows, "network"), overall(rows, sgbm_method)
    if not net["pixels"]:
        return "verdict: no valid pixels were scored"
    parts = []
    for t in ("o(0.5)", "o(2)"):
        better = net[t] < sgbm[t]
        parts.append(f"{'better' if better else 'not better'} than {sgbm_method} at {t} "
                     f"({net[t]:.4f} vs {sgbm[t]:.4f})")
    ratio = net["o(0.5)"] / sgbm["o(0.5)"] if sgbm["o(0.5)"] else float("inf")
    return (f"verdict: the network is {parts[0]} and {parts[1]}; o(0.5) ratio network / SGBM {ratio:.2f} "
            f"(GigaDepth's: 0.18; the goal: at most 0.5)")


def evaluate(checkpoint: str | Path, data_dir: str | Path, out_dir: str | Path, split: str = "test",
             device: str = "cpu", depth_bins=DEPTH_BINS, max_frames: int = 0, images: int = 8,
             progress: bool = True, precision: str = "float32", val_data: str | Path | None = None,
             val_split: str = "train", val_frames: int = 8, progress_bar: bool = True) -> list[dict]:
    """Evaluate a checkpoint and StereoSGBM (plain and LCN) on `split` of data_dir; write OUT/eval.md,
    OUT/eval.csv and OUT/errors/*.png (IR | network error | SGBM error, first `images` frames, with a
    legend). Returns the table rows. progress: print the table, with a progress bar (progress_bar=False:
    without).

    SGBM's disparity range reaches the nearest depth the data holds (sgbm_nearest_depth over the
    evaluated and validation frames). Its preprocessing (plain or LCN) is chosen by o(0.5) on
    `val_frames` frames spread over `val_split` of val_data, never on the evaluated frames; without
    val_data it is plain (GigaDepth's)."""
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    model, cfg, rig = load_model(checkpoint, device)
    frames, data_rig, _ = list_frames(data_dir, split)
    check_rig(rig, data_rig, f"checkpoint {checkpoint}", str(data_dir))
    reference = load_reference(data_dir, rig)
    if max_frames > 0:
        frames = frames[:max_frames]
    validation: list[FrameRef] = []
    if val_data is not None:
        all_val, val_rig, _ = list_frames(val_data, val_split)
        check_rig(rig, val_rig, f"checkpoint {checkpoint}", str(val_data))
        validation = spread(all_val, val_frames)
        if any((ref.path, ref.scene_index, ref.frame_index) in {(f.path, f.scene_index, f.frame_index)
                                                                 for f in frames} for ref in validation):
            raise DataError(f"{val_data}: validation frames (split {val_split!r}) overlap the evaluated "
                            f"frames of {data_dir} (split {split!r}); give another split or dataset")
    nearest = sgbm_nearest_depth(frames + validation, rig)
    n_disp = num_disparities_for(rig, nearest)
    if validation:
        chosen, val_rates = choose_preprocessing(validation, load_reference(val_data, rig), n_disp)
        choice = (f"SGBM preprocessing chosen on {len(validation)} validation frame(s) of {val_data} (split "
                  f"{val_split!r}) by o(0.5): " + ", ".join(f"{k} {v:.4f}" for k, v in val_rates.items())
                  + f" -> {chosen}")
    else:
        chosen = "plain"
        choice = "SGBM preprocessing: plain (no validation frames given: --val-data; never chosen on test)"
    sgbm_chosen = f"sgbm-{chosen}"
    methods = ("network", *(f"sgbm-{p}" for p in PREPROCESSINGS))
    (out_dir / "errors").mkdir(parents=True, exist_ok=True)
    bins = list(zip(depth_bins[:-1], depth_bins[1:], strict=True))
    ranges = [("all", None)] + [(f"{a:g}-{b:g}", (a, b)) for a, b in bins]
    counts = {(m, r): np.zeros(2 + len(THRESHOLDS), np.int64) for m in methods for r, _ in ranges}
    for n, ref in enumerate(tqdm(frames, desc="eval", unit="frame", disable=not (progress and progress_bar))):
        f = ref.read(EVAL_CHANNELS)
        ir, gt = f["ir"].astype(np.float32), f["disparity"].astype(np.float64)
        valid = valid_pixels(f)
        depth = disparity_to_depth(gt, rig)
        preds = {"network": predict_disparity(model, rig, ir, device, precision)[0]}
        for p in PREPROCESSINGS:
            preds[f"sgbm-{p}"] = sgbm_disparity(ir, reference, n_disp, preprocessing=p)
        # what each method can represent: SGBM disparities 0 .. n_disp - 1, the network any column
        # inside the projector image
        column = depth_to_projector_column(depth, rig, normalised=True)
        reachable = {"network": (column >= 0) & (column <= 1)}
        reachable |= {f"sgbm-{p}": gt <= n_disp - 1 for p in PREPROCESSINGS}
        for method, pred in preds.items():
            for name, lim in ranges:
                sel = valid if lim is None else valid & (depth >= lim[0]) & (depth < lim[1])
                pixels, outliers = outlier_counts(pred, gt, sel)
                outside = int((sel & ~reachable[method]).sum())
                counts[(method, name)] += np.array([pixels, outside, *outliers])
        if n < images:
            grey = cv2.cvtColor(_to_grey(ir), cv2.COLOR_GRAY2BGR)
            panels = [titled(grey, "IR", PANEL_WIDTH)] + [
                titled(error_image(preds[m] - gt, valid), f"{m} |err|", PANEL_WIDTH)
                for m in ("network", sgbm_chosen)
            ]
            sep = np.full((panels[0].shape[0], 2, 3), 255, np.uint8)
            strip = np.concatenate([p for panel in panels for p in (panel, sep)][:-1], axis=1)
            strip = with_legend(strip, 0.0, 5.0, "px |disparity error|", ERROR_SWATCHES)
            name = f"scene_{ref.scene_index:07d}_frame_{ref.frame_index}.png"
            write_image(out_dir / "errors" / name, strip)
    rows = []
    for (method, name), c in counts.items():
        row = {"method": method, "range": name, "pixels": int(c[0]), "outside": int(c[1]),
               "chosen": method == sgbm_chosen}
        for k, t in enumerate(THRESHOLDS):
            row[f"o({t:g})"] = c[2 + k] / c[0] if c[0] else float("nan")
        rows.append(row)
    table = format_table(rows)
    outside = overall(rows, sgbm_chosen)["outside"]
    header = (
        f"Evaluation of {checkpoint} ({precision} inference) on {len(frames)} frame(s) of {data_dir} "
        f"(split {split!r}).\n\n"
        "o(t): the share of valid pixels (pattern visible, finite GT) whose disparity is off by more than "
        "t camera pixels at full resolution; lower is better. A pixel a method gives no estimate for, or "
        "whose GT lies outside the method's range ('outside range'), counts as an outlier.\n"
        f"SGBM: {n_disp} disparities (reaching {nearest:.3g} m, the nearest depth of the config and the "
        f"data), block 5, P1 200, P2 800; {outside} valid pixel(s) lie outside its range. {choice}; "
        f"'sgbm-plain' and 'sgbm-lcn' are both listed.\n"
        f"Reference: {GIGADEPTH_REFERENCE}.\n\n")
    line = verdict(rows, sgbm_chosen)
    atomic_write_bytes(out_dir / "eval.md", (header + table + "\n" + line + "\n").encode())
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(out_dir / "eval.csv", buf.getvalue().encode())
    if progress:
        print(header + table + "\n" + line)
        print(f"evaluated {len(frames)} frame(s); table in {out_dir / 'eval.md'} and eval.csv, "
              f"error images (with a legend) in {out_dir / 'errors'}")
    return rows


def _to_grey(ir: np.ndarray) -> np.ndarray:
    scale = max(float(np.percentile(ir, 99.5)), 1e-12)
    return np.clip(ir / scale * 255, 0, 255).astype(np.uint8)
