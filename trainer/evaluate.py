"""Evaluation: outlier rates o(t) of the network and of StereoSGBM on the same frames, error images.

The counting is trainer/scoring.py's Scorer (the one training's validation uses too) over the methods
as objects; this module sizes and chooses the SGBM baselines, and writes the tables and images.

o(t) is the share of valid pixels whose disparity error exceeds t camera pixels at full resolution
(t = 0.5, 1, 2, 5). Valid: the pattern is visible and the GT disparity is finite and positive. A pixel a
method gives no estimate for counts as an outlier, so no method gains by abstaining. The network's
half-resolution output sits on pixels (2i, 2j); it is converted column -> depth -> disparity with
dotsim.rig there and brought to full resolution by interpolation that keeps those samples exactly and
does not blend across depth jumps; on a depth edge each pixel takes the nearby sample whose surface its
window's dots match in the data's pattern (trainer.upsampling.full_resolution_disparity). Rows are split
by GT depth range as well as overall, and by pixel class (on / off the edge mask, slanted, solvable or
not: dotsim/solvable.py); a joint table says which pixels both methods, only one or neither get wrong,
and a line how many of each method's estimates lie outside the rig's feasible disparity range.

Data of a stereo pair (frames storing a stereo channel of dotsim/channels.py, `ir_right`:
docs/FORMAT.md) get a row more, 'sgbm-stereo': SGBM between the left and right IR, GigaDepth's baseline
on captured data (trainer.sgbm.stereo_sgbm_disparity, its range sized to the data with the pair's
baseline). Its left-right disparity d_s = fx B_s / z is
scored as the depth it gives, in the projector disparity's pixels: d_s B / B_s (B: the projector's
baseline), so every row judges the same depth error alike. Frames storing `device_depth` (the device's
own depth: recordings, or renders with [device_depth] on) get a row 'device' (trainer.scoring's
DeviceDepthMethod: that depth as disparity, a pixel without a reading an outlier). A stride-2 network
gets a row 'half-res floor' (trainer.scoring's HalfResolutionFloor): the GT taken at its output pixels and
brought to full resolution as its output is, the errors its output resolution alone leaves.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dotsim.dataset.frames import derivable_channels
from dotsim.file_io import atomic_write_bytes
from dotsim.frame_source import FrameRef, FrameSource
from dotsim.images import write_image
from dotsim.rig.geometry import Rig, disparity_to_depth
from dotsim.rig.stereo import stereo_baseline
from dotsim.solvable import SOLVABLE_SNR
from trainer.checkpoint import check_rig, load_model
from trainer.metrics import THRESHOLDS, outlier_rate, ratio, valid_pixels
from trainer.samples import DataError
from trainer.scoring import (
    CLASSES,
    DEPTH_BINS,
    SCORED_CHANNELS,
    SLANT,
    DeviceDepthMethod,
    HalfResolutionFloor,
    NetworkMethod,
    Scorer,
    SgbmMethod,
    StereoSgbmMethod,
    depth_ranges,
    error_strip,
)
from trainer.sgbm import PREPROCESSINGS, max_disparity, num_disparities_for
from trainer.upsampling import pattern_reference


def load_reference(data: FrameSource) -> np.ndarray:
    """The data's pattern (DATASET/pattern.png, or an export's) as seen from infinity on the camera grid."""
    return pattern_reference(data.pattern, data.rig)


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


def choose_preprocessing(frames: list[FrameRef], validation: FrameSource | None, num_disparities: int
                         ) -> tuple[str, str]:
    """(the SGBM preprocessing with the lower o(0.5) on the validation `frames` of `validation`, a line
    saying how it was chosen); plain (GigaDepth's) without validation frames. Never the evaluated
    frames: the choice must not see the test."""
    if not frames:
        return "plain", ("SGBM preprocessing: plain (no validation frames given: --val-data; never chosen on "
                         "test)")
    reference = load_reference(validation)
    scorer = Scorer([SgbmMethod(reference, num_disparities, p) for p in PREPROCESSINGS], validation.rig,
                    validation.pattern, classes=("all",), thresholds=(0.5,))
    for ref in frames:
        scorer.add(ref)
    rates = {r["method"].removeprefix("sgbm-"): r["o(0.5)"] for r in scorer.rows()}
    chosen = min(PREPROCESSINGS, key=lambda name: (not rates[name] <= 1, rates[name]))
    return chosen, (f"SGBM preprocessing chosen on {len(frames)} validation frame(s) of {validation.name} "
                    f"(split {validation.split!r}) by o(0.5): "
                    + ", ".join(f"{k} {v:.4f}" for k, v in rates.items()) + f" -> {chosen}")


def eval_methods(model, data: FrameSource, nearest: float, device: str, precision: str) -> list:
    """The network, SGBM plain and LCN (their range reaching `nearest` metres), on a stereo pair's data
    SGBM between its two IR images (its range sized with the pair's baseline), on data whose frames
    store device_depth the device's own depth, and for a stride-2 network the half-resolution floor."""
    rig, reference = data.rig, load_reference(data)
    n_disp = num_disparities_for(rig, nearest)
    methods = [NetworkMethod(model, rig, device, precision, reference),
               *(SgbmMethod(reference, n_disp, p) for p in PREPROCESSINGS)]
    if data.stereo:
        pair_baseline = stereo_baseline(rig, data.name)
        methods.append(StereoSgbmMethod(num_disparities_for(rig, nearest, pair_baseline),
                                        rig.baseline / pair_baseline))  # d_s -> the projector disparity
    if "device_depth" in data.channels:
        methods.append(DeviceDepthMethod(rig))
    if model.cfg.stride == 2:
        methods.append(HalfResolutionFloor(reference))
    return methods


# GigaDepth's Table 2 (its supplementary material; DepthInSpace / CTD-style synthetic data: a few objects
# before a back plane, 432 wide x 512 tall; dotsim/configs/table2.toml rebuilds it): the only published
# figures on data like ours.
GIGADEPTH_REFERENCE = ("GigaDepth's Table 2 (synthetic DepthInSpace / CTD-style data, 432 x 512, "
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


def check_scorable(data: FrameSource) -> None:
    """DataError unless the frames of `data` hold what eval scores against, SCORED_CHANNELS (stored, or
    derived on read from depth or the projector column): the IR and the ground truth."""
    stored = set(data.channels)
    readable = stored | set(derivable_channels(stored, bool(stored & {"depth", "projector_column"})))
    missing = [c for c in SCORED_CHANNELS if c not in readable]
    if missing:
        held = ", ".join(sorted(data.channels)) or "no channel"
        raise DataError(f"{data.name}: its frames store {held}, not {', '.join(missing)}: nothing to score; "
                        "eval needs ground truth (a rendered dataset, or its export with --channels "
                        "ir,projector_column,visibility,edge; a capture has none)")


def evaluate(checkpoint: str | Path, data: FrameSource, out_dir: str | Path, device: str = "cpu",
             depth_bins=DEPTH_BINS, max_frames: int = 0, images: int = 8, progress: bool = True,
             precision: str = "float32", validation: FrameSource | None = None, val_frames: int = 8,
             progress_bar: bool = True) -> list[dict]:
    """Evaluate a checkpoint and StereoSGBM (plain and LCN; left-right too on a stereo pair's data) on
    the frames of `data` (dotsim.frame_source.open_source); write OUT/eval.md, OUT/eval.csv and
    OUT/errors/*.png (IR | network error | SGBM error, first `images` frames, with a legend). Returns the
    table rows. progress: print the table, with a progress bar (progress_bar=False: without).

    SGBM's disparity range reaches the nearest depth the data holds (sgbm_nearest_depth over the
    evaluated and validation frames). Its preprocessing (plain or LCN) is chosen by o(0.5) on
    `val_frames` frames spread over `validation`, never on the evaluated frames; without it it is
    plain (GigaDepth's)."""
    out_dir = Path(out_dir)
    model, _, rig = load_model(checkpoint, device)
    check_scorable(data)
    check_rig(rig, data.rig, f"checkpoint {checkpoint}", data.name)
    data = data.first(max_frames)
    held_out: list[FrameRef] = []
    if validation is not None:
        check_rig(rig, validation.rig, f"checkpoint {checkpoint}", validation.name)
        held_out = validation.held_out(val_frames, data, "evaluated")
    nearest = sgbm_nearest_depth(data.frames + held_out, rig)
    chosen, choice = choose_preprocessing(held_out, validation, num_disparities_for(rig, nearest))
    # the rig's feasible disparities for this data: from its max_depth to the nearest depth SGBM reaches
    feasible = (max_disparity(rig, rig.max_depth), max_disparity(rig, nearest))
    scorer = Scorer(eval_methods(model, data, nearest, device, precision), rig, data.pattern,
                    depth_ranges(depth_bins, rig.max_depth), feasible=feasible,
                    joint=("network", f"sgbm-{chosen}"))
    (out_dir / "errors").mkdir(parents=True, exist_ok=True)
    bar = tqdm(data.frames, desc="eval", unit="frame", disable=not (progress and progress_bar))
    for n, ref in enumerate(bar):
        frame, preds = scorer.add(ref)
        if n < images:
            write_image(out_dir / "errors" / f"scene_{ref.scene_index:07d}_frame_{ref.frame_index}.png",
                        error_strip(frame, {m: preds[m] for m in scorer.joint_of}))
    rows = scorer.rows(chosen=f"sgbm-{chosen}")
    text = report(scorer, rows, f"{checkpoint} ({precision} inference)", data, nearest, choice)
    atomic_write_bytes(out_dir / "eval.md", text.encode())
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    atomic_write_bytes(out_dir / "eval.csv", buf.getvalue().encode())
    if progress:
        print(text.rstrip("\n"))
        print(f"evaluated {len(data.frames)} frame(s); table in {out_dir / 'eval.md'} and eval.csv, "
              f"error images (with a legend) in {out_dir / 'errors'}")
    return rows


def report(scorer: Scorer, rows: list[dict], what: str, data: FrameSource, nearest: float, choice: str
           ) -> str:
    """eval.md: what was evaluated and how, the tables by depth range and pixel class, the joint table,
    the estimates outside the feasible range, GigaDepth's reference figures and the verdict."""
    rig, chosen = data.rig, chosen_sgbm(rows)
    sgbm = next(m for m in scorer.methods if isinstance(m, SgbmMethod))
    stereo = next((m for m in scorer.methods if isinstance(m, StereoSgbmMethod)), None)
    device = next((m for m in scorer.methods if isinstance(m, DeviceDepthMethod)), None)
    floor = next((m for m in scorer.methods if isinstance(m, HalfResolutionFloor)), None)
    table = format_table([r for r in rows if r["range"] not in CLASSES])
    by_class = [r for r in rows if r["range"] in CLASSES]
    table += ("\nBy pixel class (the edge mask as the frames store it; slanted: off it, the GT disparity "
              f"changing more than {SLANT:g} px per px along the row or down the column; solvable: the "
              "9 x 9 window's dots "
              f"{SOLVABLE_SNR:g} noise sigmas strong, dotsim/solvable.py"
              + ("" if row_of(rows, "network", "solvable") else "; not given: the frames record no sensor "
                 "noise") + "):\n\n"
              + format_table(by_class, "pixel class"))
    table += ("\nWhich pixels the network and the chosen SGBM get wrong (shares of the pixels of the set):"
              "\n\n" + joint_table(scorer.joint, chosen))
    total = overall(rows, "network")["pixels"]
    low, high = scorer.feasible
    table += (f"\nEstimates outside the rig's feasible disparity range ({low:.3g}-{high:.3g} "
              f"px: depths {nearest:.3g}-{rig.max_depth:g} m), shares of the valid pixels: "
              + ", ".join(f"{m} {outlier_rate(v, total):.4f}" for m, v in scorer.infeasible.items()) + ".\n")
    outside = overall(rows, chosen)["outside"]
    header = (
        f"Evaluation of {what} on {len(data.frames)} frame(s) of {data.name} (split {data.split!r}).\n\n"
        "o(t): the share of valid pixels (pattern visible, finite GT) whose disparity is off by more than "
        "t camera pixels at full resolution; lower is better. A pixel a method gives no estimate for, or "
        "whose GT lies outside the method's range ('outside range'), counts as an outlier.\n"
        f"SGBM: {sgbm.num_disparities} disparities (reaching {nearest:.3g} m, the nearest depth of the "
        f"config and the data), block 5, P1 200, P2 800; {outside} valid pixel(s) lie outside its range. "
        f"{choice}; "
        f"'sgbm-plain' and 'sgbm-lcn' are both listed.\n"
        + ("" if stereo is None else
           f"sgbm-stereo: SGBM between the left and right IR ({stereo.num_disparities} disparities, "
           "block 5, P1 200, P2 800, no LCN; GigaDepth's captured-data baseline), its disparity scored as "
           f"the depth it gives, in projector disparity px (x {stereo.to_projector:.3g}: the projector's "
           "baseline over the pair's).\n")
        + ("" if device is None else
           f"{device.name}: {device.label} (the frames' device_depth channel: a recording's, or the "
           "simulated device's, docs/DEVICE_DEPTH.md), scored as the disparity fx b / z of its depth; a "
           "pixel without a reading is an outlier.\n")
        + ("" if floor is None else
           f"{floor.name}: the GT disparity taken at the network's half-resolution output pixels and brought "
           "to full resolution as its output is: what a perfect network at this resolution still gets "
           "wrong (on depth edges, where a pixel near samples on two surfaces takes the one its window's "
           "dots match, and that is sometimes the wrong one).\n")
        + f"Reference: {GIGADEPTH_REFERENCE}.\n\n")
    return header + table + "\n" + verdict(rows, chosen) + "\n"
