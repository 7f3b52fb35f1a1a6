"""The scaling curve: o(0.5) of a network against the pixel-samples it trained on (steps x batch x crop
pixels), at several budgets, on a like-for-like test (new scenes of the training meshes, as DepthInSpace
tests) and a disjoint one (meshes never seen), with a power law fitted per test that says what budget
would reach a target rate (GigaDepth's Table 2: 1.88 %).

    python -m bench.trainer_scaling --config train_table2 --data data/table2/train \
        --seen-test-data data/table2/test_seen --test-data data/table2/test \
        --budgets 2e7,5e7,1.2e8,3e8 --out out/scaling/table2
    python -m bench.trainer_scaling --report out/scaling/table2

Each budget trains its own run from scratch (the config sized to its steps as bench.trainer_accuracy
sizes a run, one torch thread), so every point has a whole learning-rate schedule; a published run of
1.8e10 pixel-samples is GigaDepth's 20,480 steps of 4 full 432 x 512 frames. Each run appends one line
to OUT/results.jsonl (budget, steps, o(0.5) and o(5) per test over `--test-frames` frames spread over
each test set, the network only: trainer.scoring's Scorer, as bench.trainer_screen scores); a rerun skips
the budgets already there. `--run CHECKPOINT` adds a run trained elsewhere on --data as a
point (bench.trainer_accuracy's 60-minute run, sized the same way: its steps and crops read from the
checkpoint, its network the one --config builds), scored as the budgets are. A GPU's point (bench.gpu_check
--sections table2) is a line of the same form, with its device; the report fits the points trained on
the most common number of frames. The fit is o = a * N^-b by least squares in log-log space (the points
below a rate of 0 are left out); with fewer than two points, or a slope that does not fall, no budget
is named. Step counts, not minutes, are the abscissa: the runs may share a machine.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import torch

from bench.trainer_accuracy import sized_config
from bench.trainer_screen import append_line, rates_by_class, read_results
from dotsim.frame_source import open_source
from trainer.checkpoint import CHECKPOINT, load_checkpoint
from trainer.config import load_config
from trainer.samples import DataError
from trainer.train import train

GIGADEPTH_TABLE2_RATE = 0.0188  # o(0.5) GigaDepth reports in its Table 2
GIGADEPTH_TABLE2_PIXEL_SAMPLES = 20480 * 4 * 432 * 512  # 1.81e10: its Table 2 training
DEFAULT_BUDGETS = [2e7, 5e7, 1.2e8, 3e8]


def pixel_samples_per_step(batch: int, crop_width: int, crop_height: int, width: int, height: int) -> int:
    """Pixels one training step reads: batch x crop (full frames where a crop side is 0).

    >>> pixel_samples_per_step(4, 96, 64, 432, 512)
    24576
    >>> pixel_samples_per_step(4, 0, 0, 432, 512)
    884736
    """
    return batch * (crop_width or width) * (crop_height or height)


def power_law_fit(budgets, rates) -> tuple[float, float] | None:
    """(a, b) of rate = a * budget^-b fitted by least squares on log(rate) against log(budget), over the
    points whose rate is above 0; None with fewer than two such points.

    >>> a, b = power_law_fit([1e6, 1e7, 1e8], [0.4, 0.2, 0.1])
    >>> round(b, 4), round(a * 1e8 ** -b, 4)
    (0.301, 0.1)
    >>> a, b = power_law_fit([2e7, 5e7, 1.2e8, 3e8], [0.9 * n ** -0.35 for n in (2e7, 5e7, 1.2e8, 3e8)])
    >>> round(a, 9), round(b, 9), round(0.9 * budget_for(0.0188, (a, b)) ** -0.35, 9)
    (0.9, 0.35, 0.0188)
    >>> power_law_fit([1e6, 1e7], [0.0, 0.3]) is None  # a rate of 0 has no logarithm: one point left
    True
    >>> budget_for(0.01, power_law_fit([1e6, 1e7], [0.2, 0.3])) is None  # worse with more: no budget
    True
    """
    points = [(math.log(n), math.log(r)) for n, r in zip(budgets, rates, strict=True) if r > 0]
    if len(points) < 2:
        return None
    x, y = np.array(points).T
    slope, intercept = np.polyfit(x, y, 1)
    return float(math.exp(intercept)), float(-slope)


def budget_for(rate: float, fit: tuple[float, float] | None) -> float | None:
    """The budget at which the fitted power law reaches `rate`; None when there is no fit or the rate
    does not fall with the budget (b <= 0); inf when the slope is too flat for any float budget.

    >>> round(budget_for(0.1, (0.4 * 1e6 ** 0.5, 0.5)))
    16000000
    >>> budget_for(0.1, (0.3, 0.0)) is None, budget_for(0.01, (0.3, 1e-6))
    (True, inf)
    """
    if fit is None or fit[1] <= 0:
        return None
    a, b = fit
    log_budget = (math.log(a) - math.log(rate)) / b
    return math.exp(log_budget) if log_budget < math.log(sys.float_info.max) else math.inf


def curve_point(checkpoint: Path, steps: int, per_step: int, config: str, source, tests: dict, count: int,
                device: str = "cpu") -> dict:
    """One point of the curve, as a line of results.jsonl: a run of `steps` steps of `per_step`
    pixel-samples trained on `source` (a FrameSource), with o(0.5) and o(5) of its checkpoint on `count`
    frames spread over each of `tests` ({name: FrameSource}), the network run on `device`."""
    return {"pixel_samples": steps * per_step, "steps": steps, "config": config, "data": source.name,
            "frames": len(source.frames),
            "tests": {name: rates_by_class(checkpoint, test, source, count, device)["all"]
                      for name, test in tests.items()}}


def run_steps(checkpoint: Path, config: str, model: dict) -> tuple[int, int]:
    """(steps, pixel-samples per step) of a run trained elsewhere, read from its checkpoint, which must hold
    the network of `config` (its [model] section `model`): a run of another network is not a point of this
    curve."""
    ckpt, cfg, rig = load_checkpoint(checkpoint)
    mine, theirs = cfg.to_dict()["model"], model
    if mine != theirs:
        diffs = ", ".join(f"{k} {mine[k]} (--config: {theirs[k]})" for k in theirs if mine[k] != theirs[k])
        raise DataError(f"{checkpoint}: its network differs from --config {config}'s in [model] {diffs}; "
                        "allowed: a run of the network the curve is of")
    if "step" not in ckpt:
        raise DataError(f"{checkpoint}: no 'step' entry: not a checkpoint trainer.train wrote")
    return ckpt["step"], pixel_samples_per_step(cfg.train.batch_size, cfg.data.crop_width,
                                                cfg.data.crop_height, rig.camera.width, rig.camera.height)


def budgets_list(text: str) -> list[float]:
    """Comma-separated pixel-sample budgets, ascending, each above 0.

    >>> budgets_list("5e7, 2e7,1.2e8")
    [20000000.0, 50000000.0, 120000000.0]
    """
    try:
        values = sorted(float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--budgets {text!r}: comma-separated numbers "
                                         "(pixel-samples)") from None
    if not values or values[0] <= 0:
        raise argparse.ArgumentTypeError(f"--budgets {text!r}: every budget must be above 0")
    return values


def report(folder: Path, target: float = GIGADEPTH_TABLE2_RATE) -> str:
    """The markdown table of a folder's points and, per test, the fit and the budget it names for
    `target`. The fit takes the points trained on the most common number of frames: a point trained on
    fewer (a GPU run on the frames one device call could carry) is shown but would bend the curve."""
    rows = sorted(read_results(folder), key=lambda r: r["pixel_samples"])
    tests = list(dict.fromkeys(t for r in rows for t in r["tests"]))
    frames = Counter(r["frames"] for r in rows).most_common(1)[0][0] if rows else None
    header = " | ".join(f"{t} o(0.5) | {t} o(5)" for t in tests)
    lines = [f"| pixel-samples | steps | frames | where | {header} |", "|" + "---|" * (4 + 2 * len(tests))]
    for r in rows:
        cells = " | ".join(f"{r['tests'][t]['o(0.5)']:.4f} | {r['tests'][t]['o(5)']:.4f}" if t in r["tests"]
                           else "- | -" for t in tests)
        where = r.get("device", "cpu")
        lines.append(f"| {r['pixel_samples']:.3g} | {r['steps']} | {r['frames']} | {where} | {cells} |")
    lines.append("")
    fitted = [r for r in rows if r["frames"] == frames]
    if len(fitted) < len(rows):
        lines.append(f"The fits take the {len(fitted)} points trained on {frames} frames; the others are "
                     "not fitted.")
    for t in tests:
        points = [(r["pixel_samples"], r["tests"][t]["o(0.5)"]) for r in fitted if t in r["tests"]]
        fit = power_law_fit(*zip(*points, strict=True)) if len(points) >= 2 else None
        need = budget_for(target, fit)
        if fit is None:
            lines.append(f"{t}: fewer than two points above 0, no fit")
            continue
        lines.append(f"{t}: o(0.5) = {fit[0]:.4g} x N^-{fit[1]:.4f} over {len(points)} points; "
                     + (f"{target:.2%} at N = {need:.3g} pixel-samples "
                        f"({need / GIGADEPTH_TABLE2_PIXEL_SAMPLES:.3g} x GigaDepth's Table 2 run)"
                        if need is not None and need < math.inf else
                        "the rate falls too slowly or not at all with the budget: no budget named"))
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", default="train_table2", help="training config: a built-in name or a file")
    parser.add_argument("--data", type=Path, help="dataset whose --split frames are trained on")
    parser.add_argument("--split", default="train")
    parser.add_argument("--seen-test-data", type=Path,
                        help="test split of new scenes of the training meshes (the like-for-like test)")
    parser.add_argument("--test-data", type=Path, help="test split of meshes never seen (the disjoint test)")
    parser.add_argument("--test-frames", type=int, default=16, help="frames spread over each test set")
    parser.add_argument("--budgets", type=budgets_list,
                        help="pixel-samples per run, comma-separated (at least four for a curve; default "
                        "2e7,5e7,1.2e8,3e8, none where --run is given)")
    parser.add_argument("--target", type=float, default=GIGADEPTH_TABLE2_RATE,
                        help="o(0.5) the fit names a budget for (default GigaDepth's 0.0188)")
    parser.add_argument("--run", type=Path, action="append", default=[], metavar="CHECKPOINT",
                        help="a run trained elsewhere on --data (bench.trainer_accuracy's) to add as a "
                        "point; repeatable; no budget is trained then unless --budgets names some")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=Path("out/scaling"))
    parser.add_argument("--report", type=Path, metavar="DIR", help="print DIR's table and fits and exit")
    args = parser.parse_args(argv)
    if args.report:
        print(report(args.report, args.target))
        return 0
    if args.data is None or (args.seen_test_data is None and args.test_data is None):
        parser.error("--data and at least one of --seen-test-data / --test-data are needed (or --report DIR)")
    torch.set_num_threads(args.threads)
    source = open_source(args.data, args.split)
    tests = {name: open_source(path, "test") for name, path in
             (("seen meshes", args.seen_test_data), ("disjoint meshes", args.test_data)) if path is not None}
    base = load_config(args.config).to_dict()
    cam = source.rig.camera
    per_step = pixel_samples_per_step(base["train"]["batch_size"], base["data"]["crop_width"],
                                      base["data"]["crop_height"], cam.width, cam.height)
    results = args.out / "results.jsonl"
    done = {json.loads(line)["pixel_samples"] for line in results.read_text().splitlines() if line} \
        if results.exists() else set()
    steps_per_epoch = max(len(source.frames) // base["train"]["batch_size"], 1)
    for checkpoint in args.run:
        try:
            steps, run_per_step = run_steps(checkpoint, args.config, base["model"])
        except DataError as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        if steps * run_per_step in done:
            print(f"{checkpoint}: {steps * run_per_step:.3g} pixel-samples already in {results}, skipped")
            continue
        line = curve_point(checkpoint, steps, run_per_step, args.config, source, tests, args.test_frames)
        append_line(results, line | {"run": str(checkpoint)})
        done.add(line["pixel_samples"])
    budgets = args.budgets if args.budgets is not None else [] if args.run else DEFAULT_BUDGETS
    for budget in budgets:
        steps = max(1, round(budget / per_step))
        if steps * per_step in done:
            print(f"{steps * per_step:.3g} pixel-samples: already in {results}, skipped")
            continue
        # enough epochs to hold every step (fewer would end the run early, short of its budget)
        cfg = sized_config(base, steps, math.ceil(steps / steps_per_epoch), args.config)
        run = args.out / f"run_{steps}"
        result = train(cfg, source, run, progress=False)
        line = curve_point(run / CHECKPOINT, result["step"], per_step, args.config, source, tests,
                           args.test_frames)
        append_line(results, line)
    print(report(args.out, args.target))
    return 0


if __name__ == "__main__":
    sys.exit(main())
