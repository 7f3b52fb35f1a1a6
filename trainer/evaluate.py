"""Evaluation: outlier rates o(t) of the network and of StereoSGBM on the same frames, error images.

o(t) is the share of valid pixels whose disparity error exceeds t camera pixels at full resolution
(t = 0.5, 1, 2, 5). Valid: the pattern is visible and the GT disparity is finite and positive. A pixel a
method gives no estimate for counts as an outlier, so no method gains by abstaining. The network's
half-resolution output sits on pixels (2i, 2j); it is converted column -> depth -> disparity with
dotsim.rig there and brought to full resolution by interpolation that keeps those samples exactly and
does not blend across depth jumps (trainer.checkpoint.predict_disparity). Rows are split by GT depth range
as well as overall, and by pixel class (on / off the edge mask, solvable or not: dotsim/solvable.py);
a joint table says which pixels both methods, only one or neither get wrong, and a line how many of
each method's estimates lie outside the rig's feasible disparity range.

Data of a stereo pair (frames storing `ir_right`, docs/FORMAT.md) get a row more, 'sgbm-stereo': SGBM
between the left and right IR, GigaDepth's baseline on captured data (trainer.sgbm.stereo_sgbm_disparity,
its range sized to the data with the pair's baseline). Its left-right disparity d_s = fx B_s / z is
scored as the depth it gives, in the projector disparity's pixels: d_s B / B_s (B: the projector's
baseline), so every row judges the same depth error alike.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from dotsim.channels import CHANNEL
from dotsim.dataset.frames import derivable_channels
from dotsim.false_colour import titled, with_legend
from dotsim.file_io import atomic_write_bytes
from dotsim.images import write_image
from dotsim.rig import (
    Rig,
    depth_to_projector_column,
    disparity_to_depth,
    reference_image,
)
from dotsim.solvable import SOLVABLE_SNR, solvable_pixels
from dotsim.stereo import stereo_baseline
from trainer.checkpoint import check_rig, load_model, predict_disparity
from trainer.data import DataError, FrameRef, check_held_out, dataset_pattern, list_frames, spread
from trainer.metrics import (
    THRESHOLDS,
    joint_outliers,
    outlier_counts,
    outlier_rate,
    outside_range,
    ratio,
    valid_pixels,
)
from trainer.sgbm import (
    PREPROCESSINGS,
    max_disparity,
    num_disparities_for,
    sgbm_disparity,
    stereo_sgbm_disparity,
)

DEPTH_BINS = (0.0, 1.0, 2.0, 4.0, 8.0, 20.0)  # metres; cut at the rig's max_depth (depth_ranges)
# depth follows from disparity: exports may hold no depth
EVAL_CHANNELS = ("ir", "visibility", "disparity", "edge")
CLASSES = ("edge", "off edge", "solvable", "not solvable")  # the pixel classes beside the depth ranges


def depth_ranges(depth_bins, max_depth: float) -> tuple[float, ...]:
    """The bin edges below a rig's max_depth, closed by it: no row for depths the rig never holds.

    >>> depth_ranges(DEPTH_BINS, 6.0), depth_ranges(DEPTH_BINS, 20.0)
    ((0.0, 1.0, 2.0, 4.0, 6.0), (0.0, 1.0, 2.0, 4.0, 8.0, 20.0))
    """
    return tuple(b for b in depth_bins if b < max_depth) + (max_depth,)


def pixel_classes(valid: np.ndarray, depth: np.ndarray, edge: np.ndarray | None = None,
                  solvable: np.ndarray | None = None, depth_bins=DEPTH_BINS) -> dict[str, np.ndarray]:
    """The valid pixels by class: "all", each GT depth range "a-b" (m), and where given on / off the
    edge mask and solvable or not (dotsim/solvable.py)."""
    with np.errstate(invalid="ignore"):
        classes = {"all": valid} | {f"{a:g}-{b:g}": valid & (depth >= a) & (depth < b)
                                    for a, b in zip(depth_bins[:-1], depth_bins[1:], strict=True)}
    if edge is not None:
        classes |= {"edge": valid & (edge > 0), "off edge": valid & ~(edge > 0)}
    if solvable is not None:
        classes |= {"solvable": valid & solvable, "not solvable": valid & ~solvable}
    return classes


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
    return reference_image(dataset_pattern(data, rig), rig, supersample=4)


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
        valid = valid_pixels(f["visibility"], f["disparity"])
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


def choose_preprocessing(frames: list[FrameRef], reference: np.ndarray, num_disparities: int
                         ) -> tuple[str, dict[str, float]]:
    """(the SGBM preprocessing with the lower o(0.5) on `frames`, {preprocessing: o(0.5)}).

    `frames` are validation frames (never the evaluated ones): the choice must not see the test."""
    outliers = dict.fromkeys(PREPROCESSINGS, 0)
    pixels = 0
    for ref in frames:
        f = ref.read(EVAL_CHANNELS)
        valid, gt = valid_pixels(f["visibility"], f["disparity"]), f["disparity"].astype(np.float64)
        pixels += int(valid.sum())
        for name in PREPROCESSINGS:
            pred = sgbm_disparity(f["ir"].astype(np.float32), reference, num_disparities, preprocessing=name)
            outliers[name] += outlier_counts(pred, gt, valid, thresholds=(0.5,))[1][0]
    rates = {name: outlier_rate(outliers[name], pixels) for name in PREPROCESSINGS}
    return min(PREPROCESSINGS, key=lambda name: (not rates[name] <= 1, rates[name])), rates


# GigaDepth's Table 2 (its supplementary material; DepthInSpace / CTD-style synthetic data: a few objects
# before a back plane, 512 x 432; dotsim/configs/table2.toml rebuilds it): the only published figures
# on data like ours.
GIGADEPTH_REFERENCE = ("GigaDepth's Table 2 (synthetic DepthInSpace / CTD-style data, 512 x 432, "
                       "dotsim/configs/table2.toml rebuilds it): SGM o(0.5) 10.4-12.9 %, GigaDepth o(0.5) "
                       "1.75-1.88 % (5.5-6.9x fewer outliers)")


def format_table(rows: list[dict], label: str = "depth range (m)") -> str:
    head = (f"| method | {label} | pixels | outside range | "
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


def row_of(rows: list[dict], method: str, pixels: str) -> dict | None:
    """The row of a method for a depth range or pixel class, or None."""
    return next((r for r in rows if r["method"] == method and r["range"] == pixels), None)


def verdict(rows: list[dict], sgbm_method: str) -> str:
    """One line: the network against the chosen SGBM at o(0.5) and o(2), the o(0.5) ratio against
    GigaDepth's and the goal, overall and on the solvable pixels."""
    net, sgbm = overall(rows, "network"), overall(rows, sgbm_method)
    if not net["pixels"]:
        return "verdict: no valid pixels were scored"
    parts = []
    for t in ("o(0.5)", "o(2)"):
        better = net[t] < sgbm[t]
        parts.append(f"{'better' if better else 'not better'} than {sgbm_method} at {t} "
                     f"({net[t]:.4f} vs {sgbm[t]:.4f})")
    line = (f"verdict: the network is {parts[0]} and {parts[1]}; o(0.5) ratio network / SGBM "
            f"{ratio(net['o(0.5)'], sgbm['o(0.5)']):.2f} (GigaDepth's: 0.18; the goal: at most 0.5)")
    net, sgbm = row_of(rows, "network", "solvable"), row_of(rows, sgbm_method, "solvable")
    if net and net["pixels"]:
        line += (f"; on the solvable pixels {net['o(0.5)']:.4f} vs {sgbm['o(0.5)']:.4f}, ratio "
                 f"{ratio(net['o(0.5)'], sgbm['o(0.5)']):.2f}")
    return line


def joint_table(joint: dict[tuple[str, float], np.ndarray], sgbm_method: str) -> str:
    """Which valid pixels the network and the chosen SGBM get wrong, per pixel set and threshold."""
    lines = [f"| pixels | t | both wrong | only the network | only {sgbm_method} | neither |",
             "|---|---|---|---|---|---|"]
    for (pixels, t), c in joint.items():
        total = int(c.sum())
        shares = " | ".join(f"{outlier_rate(int(v), total):.4f}" if total else "-" for v in c)
        lines.append(f"| {pixels} | {t:g} | {shares} |")
    return "\n".join(lines) + "\n"


def check_scorable(frame: FrameRef, data_dir) -> None:
    """DataError unless `frame` (of the data to evaluate) holds what eval scores against, EVAL_CHANNELS
    (stored, or derived on read from depth or the projector column): the IR and the ground truth."""
    stored = frame.stored_channels()
    readable = stored | set(derivable_channels(stored, bool(stored & {"depth", "projector_column"})))
    missing = [c for c in EVAL_CHANNELS if c not in readable]
    if missing:
        held = ", ".join(sorted(stored & set(CHANNEL))) or "no channel"
        raise DataError(f"{data_dir}: its frames store {held}, not {', '.join(missing)}: nothing to score; "
                        "eval needs ground truth (a rendered dataset, or its export with --channels "
                        "ir,projector_column,visibility,edge; a capture has none)")


def evaluate(checkpoint: str | Path, data_dir: str | Path, out_dir: str | Path, split: str = "test",
             device: str = "cpu", depth_bins=DEPTH_BINS, max_frames: int = 0, images: int = 8,
             progress: bool = True, precision: str = "float32", val_data: str | Path | None = None,
             val_split: str = "train", val_frames: int = 8, progress_bar: bool = True) -> list[dict]:
    """Evaluate a checkpoint and StereoSGBM (plain and LCN; left-right too on a stereo pair's data) on
    `split` of data_dir; write OUT/eval.md, OUT/eval.csv and OUT/errors/*.png (IR | network error |
    SGBM error, first `images` frames, with a legend). Returns the table rows. progress: print the
    table, with a progress bar (progress_bar=False: without).

    SGBM's disparity range reaches the nearest depth the data holds (sgbm_nearest_depth over the
    evaluated and validation frames). Its preprocessing (plain or LCN) is chosen by o(0.5) on
    `val_frames` frames spread over `val_split` of val_data, never on the evaluated frames; without
    val_data it is plain (GigaDepth's)."""
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    model, cfg, rig = load_model(checkpoint, device)
    frames, data_rig, _ = list_frames(data_dir, split)
    check_scorable(frames[0], data_dir)
    check_rig(rig, data_rig, f"checkpoint {checkpoint}", str(data_dir))
    reference = load_reference(data_dir, rig)
    depth_bins = depth_ranges(depth_bins, rig.max_depth)
    if max_frames > 0:
        frames = frames[:max_frames]
    validation: list[FrameRef] = []
    if val_data is not None:
        all_val, val_rig, _ = list_frames(val_data, val_split)
        check_rig(rig, val_rig, f"checkpoint {checkpoint}", str(val_data))
        validation = spread(all_val, val_frames)
        check_held_out(validation, frames, f"{val_data}: validation frames (split {val_split!r})",
                       f"the evaluated frames of {data_dir} (split {split!r})")
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
    channels = EVAL_CHANNELS
    if "ir_right" in frames[0].stored_channels():
        pair_baseline = stereo_baseline(rig, str(data_dir))
        n_stereo = num_disparities_for(rig, nearest, pair_baseline)
        to_projector = rig.baseline / pair_baseline  # d_s -> the projector disparity of that depth
        methods += ("sgbm-stereo",)
        channels += ("ir_right",)
    (out_dir / "errors").mkdir(parents=True, exist_ok=True)
    pattern = dataset_pattern(data_dir, rig)
    # the rig's feasible disparities for this data: from its max_depth to the nearest depth SGBM reaches
    feasible = (max_disparity(rig, rig.max_depth), max_disparity(rig, nearest))
    counts: dict[tuple[str, str], np.ndarray] = {}
    joint: dict[tuple[str, float], np.ndarray] = {}
    infeasible = dict.fromkeys(methods, 0)
    for n, ref in enumerate(tqdm(frames, desc="eval", unit="frame", disable=not (progress and progress_bar))):
        f = ref.read(channels)
        ir, gt = f["ir"].astype(np.float32), f["disparity"].astype(np.float64)
        valid = valid_pixels(f["visibility"], f["disparity"])
        depth = disparity_to_depth(gt, rig)
        solved = solvable_pixels(ir, depth, rig, pattern, ref.scene_meta())
        classes = pixel_classes(valid, depth, f["edge"], solved, depth_bins)
        preds = {"network": predict_disparity(model, rig, ir, device, precision)[0]}
        for p in PREPROCESSINGS:
            preds[f"sgbm-{p}"] = sgbm_disparity(ir, reference, n_disp, preprocessing=p)
        # what each method can represent: SGBM disparities 0 .. n_disp - 1, the network any column
        # inside the projector image (no nearer than [model] min_depth where that restricts it)
        column = depth_to_projector_column(depth, rig, normalised=True)
        with np.errstate(invalid="ignore"):
            reachable = {"network": (column >= 0) & (column <= 1) & (depth >= cfg.model.min_depth)}
        reachable |= {f"sgbm-{p}": gt <= n_disp - 1 for p in PREPROCESSINGS}
        if "sgbm-stereo" in methods:
            right = f["ir_right"].astype(np.float32)
            preds["sgbm-stereo"] = stereo_sgbm_disparity(ir, right, n_stereo) * to_projector
            reachable["sgbm-stereo"] = gt / to_projector <= n_stereo - 1
        for method, pred in preds.items():
            infeasible[method] += outside_range(pred, *feasible, valid)
            for name, sel in classes.items():
                pixels, outliers = outlier_counts(pred, gt, sel)
                outside = int((sel & ~reachable[method]).sum())
                counts[(method, name)] = counts.get((method, name), 0) + np.array([pixels, outside,
                                                                                   *outliers])
        for name in ("all", "solvable"):
            for t in THRESHOLDS if name in classes else ():
                both = joint_outliers(preds["network"], preds[sgbm_chosen], gt, classes[name], t)
                joint[(name, t)] = joint.get((name, t), 0) + np.array(both)
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
            row[f"o({t:g})"] = outlier_rate(int(c[2 + k]), int(c[0]))
        rows.append(row)
    table = format_table([r for r in rows if r["range"] not in CLASSES])
    by_class = [r for r in rows if r["range"] in CLASSES]
    table += ("\nBy pixel class (the edge mask as the frames store it; solvable: the 9 x 9 window's dots "
              f"{SOLVABLE_SNR:g} noise sigmas strong, dotsim/solvable.py"
              + ("" if row_of(rows, "network", "solvable") else "; not given: the frames record no sensor "
                 "noise") + "):\n\n"
              + format_table(by_class, "pixel class"))
    table += ("\nWhich pixels the network and the chosen SGBM get wrong (shares of the pixels of the set):"
              "\n\n" + joint_table(joint, sgbm_chosen))
    total = overall(rows, "network")["pixels"]
    table += (f"\nEstimates outside the rig's feasible disparity range ({feasible[0]:.3g}-{feasible[1]:.3g} "
              f"px: depths {nearest:.3g}-{rig.max_depth:g} m), shares of the valid pixels: "
              + ", ".join(f"{m} {outlier_rate(v, total):.4f}" for m, v in infeasible.items()) + ".\n")
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
        + ("" if "sgbm-stereo" not in methods else
           f"sgbm-stereo: SGBM between the left and right IR ({n_stereo} disparities, block 5, P1 200, "
           "P2 800, no LCN; GigaDepth's captured-data baseline), its disparity scored as the depth it "
           f"gives, in projector disparity px (x {to_projector:.3g}: the projector's baseline over the "
           "pair's).\n")
        + f"Reference: {GIGADEPTH_REFERENCE}.\n\n")
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
