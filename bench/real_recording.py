"""A network trained only on dotsim renders, run on a real recording: the vendored Kinect v1 frame
(tests/data/real/kinect_v1_ctd, its README: source and licence), against OpenCV SGBM on the same frame.

    python -m bench.real_recording [--train-scenes 40] [--test-scenes 4] [--workers 2] \
        [--minutes 35 | --steps N] [--threads 1] [--out out/real_recording]

1. renders --train-scenes train scenes and --test-scenes test scenes (test assets, seed 1) of
   bench/kinect_real.toml: the capture's rig and real pattern, camera at half size (320 x 256);
2. trains bench/train_kinect_real.toml for --steps steps, or for --minutes: the steps that fill
   them are planned from two short calibration runs (as bench.trainer_accuracy), so that the cosine
   schedule ends with the run (on a shared machine the load changes and the run ends early or late);
3. scores it on the rendered test split (`dotsim eval`'s table: ground truth there);
4. runs `dotsim infer` on the real frame, shrunk to the network's 320 x 256 (2 x 2 means);
5. runs SGBM (trainer/sgbm.py) against the pattern as seen from infinity, on the real frame at full size
   (640 x 512) and at the network's size, its preprocessing (plain or LCN) chosen on the rendered test
   frames (trainer.evaluate.choose_preprocessing: never on the real frame), its range reaching the
   network's [model] min_depth;
6. scores every disparity without ground truth (trainer/flat_regions.py): planes fitted by RANSAC to the
   hand-drawn flat regions of the frame (flat_regions.json beside it), the RMS residual about them, in
   full-resolution (640 x 512) disparity px, and the share of pixels without a plausible value (nan, or a
   depth outside min_depth .. the rig's max_depth), over the regions and over the whole frame.

Writes into --out: train/, test/ (the renders), run/ (the network), eval/ (its rendered test table),
infer/ (the prediction EXR, PNG, PLY), real_recording.json (settings, versions, the table),
real_recording.png (the real frame, each disparity, each residual map on the regions). A rerun reuses
what is there: complete scenes, the planned steps (plan.json) and a finished training.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REAL = Path(__file__).resolve().parents[1] / "tests" / "data" / "real" / "kinect_v1_ctd"
GENERATOR_CONFIG = Path(__file__).with_name("kinect_real.toml")
TRAIN_CONFIG = Path(__file__).with_name("train_kinect_real.toml")
RESIDUAL_LIMIT = 2.0  # full-resolution px at the ends of the residual pictures' colour scale
PANEL_WIDTH = 320  # px: the pictures' panels (the network's size; the full-size maps halved)


def real_frame(shape: tuple[int, int]) -> np.ndarray:
    """The vendored IR frame (H, W) float32 in [0, 1] (8-bit / 255), shrunk by whole-pixel means to
    `shape` (the network's camera: the same field at a whole fraction of the size)."""
    ir = cv2.imread(str(REAL / "ir.png"), cv2.IMREAD_UNCHANGED).astype(np.float32) / 255.0
    if ir.shape == shape:
        return ir
    return cv2.resize(ir, (shape[1], shape[0]), interpolation=cv2.INTER_AREA)


def full_size_rig(rig):
    """The rig with its camera at the real frame's full size (rig.json's camera), the projector kept."""
    from dotsim.rig.geometry import Rig

    camera = json.loads((REAL / "rig.json").read_text())["rig"]["camera"]
    return Rig.from_dict({**rig.to_dict(), "camera": camera}, f"{REAL / 'rig.json'} camera")


def epochs_for(steps: int, train_source, base: dict) -> int:
    """The epochs `steps` steps of the config `base` (a dict) make over the frames of `train_source`."""
    return max(1, round(steps / max(1, len(train_source.frames) // base["train"]["batch_size"])))


def planned_run(work: Path, train_source, minutes: float, base: dict) -> tuple[int, int]:
    """(steps, epochs) that fill `minutes` of training: from plan.json when a previous run planned them,
    else from two calibration runs (bench.trainer_accuracy's way), then written to plan.json."""
    from bench.trainer_accuracy import planned_steps, sized_config
    from dotsim.file_io import atomic_write_json as write_json
    from trainer.train import train

    plan_file = work / "plan.json"
    if plan_file.is_file():
        plan = json.loads(plan_file.read_text())
        return plan["steps"], plan["epochs"]
    short, long = (train(sized_config(base, n, 1000, TRAIN_CONFIG, cache_mb=0), train_source,
                         work / f"calibration_{n}", progress=False)["seconds"] for n in (5, 25))
    steps = planned_steps(max(long - short, 1e-3) / 20, train_source.frames, train_source.rig,
                          sized_config(base, 1, 1, TRAIN_CONFIG), minutes * 60)
    epochs = epochs_for(steps, train_source, base)
    write_json(plan_file, {"steps": steps, "epochs": epochs, "minutes": minutes,
                           "calibration_s": {"5 steps": short, "25 steps": long}})
    return steps, epochs


def sgbm_on_real(rig, reference: np.ndarray, ir: np.ndarray, min_depth: float, preprocessing: str
                 ) -> tuple[np.ndarray, int]:
    """(SGBM's disparity of `ir` against `reference` through `rig`, its numDisparities)."""
    from trainer.sgbm import num_disparities_for, sgbm_disparity

    n = num_disparities_for(rig, min_depth)
    return sgbm_disparity(ir, reference, n, preprocessing=preprocessing), n


def json_safe(value):
    """`value` with every nan (a class without pixels, a region without values) as None: JSON has no nan."""
    if isinstance(value, dict):
        return {k: json_safe(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def no_value_share(disparity: np.ndarray, plausible: tuple[float, float]) -> float:
    """Share of the frame's pixels without a plausible disparity (nan, or outside `plausible`)."""
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(disparity) & (disparity >= plausible[0]) & (disparity <= plausible[1])
    return float(1 - ok.mean())


def picture(ir: np.ndarray, labels_full: np.ndarray, maps: dict[str, tuple[np.ndarray, np.ndarray]],
            low: float, high: float) -> np.ndarray:
    """BGR: the real frame, then each method's disparity (full-resolution px); under them the regions and
    each method's residuals about its planes; two legends. Every panel PANEL_WIDTH wide (maps resized
    by nearest neighbour)."""
    from dotsim.false_colour import colourise, label_colours, titled, with_legend
    from trainer.flat_regions import residual_image
    from trainer.scoring import grey

    shape = (PANEL_WIDTH, round(PANEL_WIDTH * ir.shape[0] / ir.shape[1]))  # every panel this size (w, h)
    ir = cv2.resize(ir, shape, interpolation=cv2.INTER_AREA)
    labels_full = cv2.resize(labels_full, shape, interpolation=cv2.INTER_NEAREST)
    frame = cv2.cvtColor(grey(ir), cv2.COLOR_GRAY2BGR)
    regions = np.where(labels_full[..., None] > 0, (0.6 * frame + 0.4 * label_colours(labels_full)), frame)
    top = [titled(frame, "real IR", PANEL_WIDTH)]
    bottom = [titled(regions.astype(np.uint8), "flat regions (drawn by hand)", PANEL_WIDTH)]
    for name, (disparity, residuals) in maps.items():
        top.append(titled(cv2.resize(colourise(disparity, low, high), shape, interpolation=cv2.INTER_NEAREST),
                          f"{name} disparity", PANEL_WIDTH))
        bottom.append(titled(cv2.resize(residual_image(residuals, RESIDUAL_LIMIT), shape,
                                        interpolation=cv2.INTER_NEAREST), f"{name} residual", PANEL_WIDTH))

    def strip(panels, low, high, unit):
        sep = np.full((panels[0].shape[0], 2, 3), 255, np.uint8)
        return with_legend(np.concatenate([p for panel in panels for p in (panel, sep)][:-1], axis=1),
                           low, high, unit, (((0, 0, 0), "black: no plausible value"),))

    top = strip(top, low, high, "px disparity, full resolution (near = high)")
    bottom = strip(bottom, -RESIDUAL_LIMIT, RESIDUAL_LIMIT, "px from the region's plane (green: on it)")
    return np.concatenate([top, np.full((6, top.shape[1], 3), 255, np.uint8), bottom], axis=0)


def format_rows(rows: list[dict], names: list[str]) -> str:
    """The markdown table: one row per method."""
    head = ("| method | size | frame: no value | regions: no value | RMS (px) | within 1 px | "
            "RMS within 1 px | " + " | ".join(f"{n} RMS" for n in names) + " |")
    lines = [head, "|" + "---|" * (7 + len(names))]
    for r in rows:
        per = {x["region"]: x for x in r["regions"]}
        every = per["all"]
        lines.append(f"| {r['method']} | {r['size']} | {r['frame no value']:.3f} | {every['no value']:.3f} "
                     f"| {every['rms']:.3f} | {every['within']:.3f} | {every['rms within']:.3f} | "
                     + " | ".join(f"{per[n]['rms']:.3f}" for n in names) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.real_recording",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--train-scenes", type=int, default=40, help="rendered training scenes (default 40)")
    parser.add_argument("--test-scenes", type=int, default=4, help="rendered test scenes (default 4)")
    parser.add_argument("--workers", type=int, default=2, help="render processes (default 2)")
    parser.add_argument("--minutes", type=float, default=35.0,
                        help="training budget (default 35): the steps that fill it are planned, and the run "
                        "stops at 1.1 times it")
    parser.add_argument("--steps", type=int, default=0,
                        help="train this many steps instead of planning them from --minutes (a result that "
                        "does not depend on the machine's load; --minutes x 1.1 still stops it)")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (default 1)")
    parser.add_argument("--out", type=Path, default=Path("out/real_recording"), help="work folder")
    args = parser.parse_args(argv)

    import torch

    from bench.trainer_accuracy import sized_config
    from commands.cli import main as dotsim
    from dotsim.file_io import atomic_write_json as write_json
    from dotsim.frame_source import open_source
    from dotsim.images import write_image
    from dotsim.prediction_file import output_name, read_prediction
    from dotsim.rig.geometry import depth_to_disparity, reference_image
    from dotsim.version import __version__
    from generator.driver import generate
    from trainer.checkpoint import load_model
    from trainer.config import load_config
    from trainer.evaluate import choose_preprocessing, evaluate, format_table
    from trainer.flat_regions import read_regions, region_residuals, score_regions
    from trainer.sgbm import PREPROCESSINGS, num_disparities_for
    from trainer.train import train

    torch.set_num_threads(args.threads)
    work = args.out
    work.mkdir(parents=True, exist_ok=True)
    rendered = {}
    for split, scenes, seed in (("train", args.train_scenes, 0), ("test", args.test_scenes, 1)):
        summary = generate(GENERATOR_CONFIG, work / split, split, scenes, workers=args.workers, seed=seed,
                           progress=True)
        rendered[split] = {"scenes": scenes, "rendered": summary.done, "seconds": round(summary.seconds, 1)}
    train_source, test_source = open_source(work / "train", "train"), open_source(work / "test", "test")
    rig = train_source.rig

    base = load_config(TRAIN_CONFIG).to_dict()
    if args.steps:
        steps, epochs = args.steps, epochs_for(args.steps, train_source, base)
    else:
        steps, epochs = planned_run(work, train_source, args.minutes, base)
    print(f"{len(train_source.frames)} train frames at {rig.camera.width}x{rig.camera.height}: "
          f"{steps} steps ({epochs} epochs)" + ("" if args.steps else f" planned for {args.minutes:g} min"),
          flush=True)
    start = time.perf_counter()
    result = train(sized_config(base, steps, epochs, TRAIN_CONFIG), train_source, work / "run", resume=True,
                   max_seconds=args.minutes * 60 * 1.1)
    minutes = round((time.perf_counter() - start) / 60, 1)
    # minutes of this call: a rerun on a finished run trains nothing and says so
    trained = {"steps": result["step"], "planned": steps, "minutes_this_call": minutes,
               "threads": args.threads}
    checkpoint = work / "run" / "checkpoint.pt"
    rows_rendered = evaluate(checkpoint, test_source, work / "eval", validation=train_source, progress=False)
    eval_table = format_table([r for r in rows_rendered if r["range"] == "all"])
    print(f"\nrendered test split ({len(test_source.frames)} frames, ground truth):\n{eval_table}")

    # the real frame at the network's size, through `dotsim infer`
    model, cfg, _ = load_model(checkpoint)
    half = real_frame((rig.camera.height, rig.camera.width))
    frame_png = work / f"real_ir_{rig.camera.width}x{rig.camera.height}.png"
    write_image(frame_png, np.rint(half * 65535).astype(np.uint16))  # 16 bit: the 2 x 2 means kept
    if dotsim(["infer", "--checkpoint", str(checkpoint), str(frame_png), "--out", str(work / "infer")]) != 0:
        return 1
    network = read_prediction(work / "infer" / f"{output_name(frame_png)}.exr")["disparity"]

    # SGBM on the real frame, at full size and at the network's, preprocessing chosen on renders
    full_rig = full_size_rig(rig)
    full_ir = real_frame((full_rig.camera.height, full_rig.camera.width))
    min_depth = cfg.model.min_depth
    chosen, why = choose_preprocessing(test_source.frames, test_source, num_disparities_for(rig, min_depth))
    print(why)
    full_reference = reference_image(test_source.pattern, full_rig, 4)
    sgbm_full, n_full = sgbm_on_real(full_rig, full_reference, full_ir, min_depth, chosen)
    half_reference = reference_image(test_source.pattern, rig, 4)
    sgbm_half, n_half = sgbm_on_real(rig, half_reference, half, min_depth, chosen)
    other = next(p for p in PREPROCESSINGS if p != chosen)  # in the table only, to show what the choice did
    sgbm_other, _ = sgbm_on_real(full_rig, full_reference, full_ir, min_depth, other)

    # every map in full-resolution disparity px; plausible: depths from min_depth to the rig's max_depth
    to_full = full_rig.camera.width / rig.camera.width
    plausible = tuple(float(depth_to_disparity(np.float64(z), full_rig)) for z in (rig.max_depth, min_depth))
    maps = {("network", "320 x 256"): network * to_full, (f"sgbm-{chosen}", "640 x 512"): sgbm_full,
            (f"sgbm-{chosen}", "320 x 256"): sgbm_half * to_full,
            (f"sgbm-{other} (not chosen)", "640 x 512"): sgbm_other}
    rows, pictured = [], {}
    labels_full, names = read_regions(REAL / "flat_regions.json", full_ir.shape)
    for (name, size), disparity in maps.items():
        labels, _ = read_regions(REAL / "flat_regions.json", disparity.shape)
        regions = score_regions(disparity, labels, names, plausible)
        rows.append({"method": name, "size": size, "frame no value": no_value_share(disparity, plausible),
                     "regions": regions})
        if "not chosen" not in name:
            residuals = region_residuals(disparity, labels, len(names), plausible)[0]
            pictured[f"{name} {size.split()[0]}"] = (disparity, residuals)
    table = format_rows(rows, names)
    low, high = np.nanpercentile(np.where(labels_full > 0, sgbm_full, np.nan), [1, 99])
    image = picture(full_ir, labels_full, pictured, float(low) - 5, float(high) + 5)
    write_image(work / "real_recording.png", image)
    write_json(work / "real_recording.json", json_safe({
        "command": "python -m bench.real_recording " + " ".join(argv if argv is not None else sys.argv[1:]),
        "generator_config": GENERATOR_CONFIG, "train_config": TRAIN_CONFIG, "rendered": rendered,
        "trained": trained, "sgbm": {"preprocessing": chosen, "chosen": why, "num_disparities":
                                     {"640 x 512": n_full, "320 x 256": n_half}},
        "plausible_disparity_full_px": plausible, "min_depth": min_depth, "max_depth": rig.max_depth,
        "rows": rows, "rendered_test_rows": rows_rendered,
        "versions": {"dotsim": __version__, "torch": torch.__version__, "numpy": np.__version__,
                     "opencv": cv2.__version__, "python": platform.python_version()}}))
    print(f"\nreal frame ({REAL / 'ir.png'}), flat regions of flat_regions.json; disparity in "
          f"full-resolution px; plausible {plausible[0]:.2f} .. {plausible[1]:.2f} px "
          f"(depth {min_depth:g} .. {rig.max_depth:g} m)"
          f"\n{table}\n\nrendered: {rendered}\ntrained: {trained}\nwrote {work / 'real_recording.json'} and "
          f"{work / 'real_recording.png'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
