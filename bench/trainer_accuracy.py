"""Accuracy of the trained network against StereoSGBM: train on a train split for a CPU time budget,
evaluate o(0.5..5) of both on a test split of disjoint scenes. Goal (issue 5): network o(0.5) at most
half of SGBM's.

    python -m bench.trainer_accuracy [--data DIR] [--test-data DIR] [--minutes 10] \
        [--config dotsim/configs/train_tiny.toml]

Data: --data (its train split) and --test-data (its test split; default --data), else the Blender
generator's output under out/: a folder holding a train and a test split, or sibling folders (e.g.
out/bench_accuracy/train and out/bench_accuracy/test from dotsim/configs/bench_accuracy.toml, whose header
has the commands), else an oracle-rendered dataset (tests/trainer_fixtures.py: random tilted walls and
boxes, exact geometry, Structure Core scaled to 128 x 94) written to a temporary folder. The output
says which. The step count is fitted to the time budget from the time per step of two short
calibration runs (5 and 25 steps; their difference leaves out start-up), and the step decay
halves the learning rate at 25, 50 and 75 % of it.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import torch

from trainer.config import config_from_dict, load_config
from trainer.data import list_frames
from trainer.evaluate import evaluate, format_table
from trainer.train import train

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))
from trainer_fixtures import make_dataset  # noqa: E402


def generated_datasets(root: Path = Path("out")) -> tuple[Path, Path] | None:
    """(train dataset, test dataset) among the finalized datasets under root, or None: the first folder
    holding both splits, else the first train-only and test-only datasets that share a parent folder
    (`dotsim generate` writes one split per folder)."""
    by_split: dict[str, list[Path]] = {"train": [], "test": []}
    for index in sorted(root.glob("**/index.json")) if root.is_dir() else []:
        counts = json.loads(index.read_text()).get("split_counts", {})
        if counts.get("train") and counts.get("test"):
            return index.parent, index.parent
        for split in by_split:
            if counts.get(split):
                by_split[split].append(index.parent)
    for train_dir in by_split["train"]:
        for test_dir in by_split["test"]:
            if train_dir.parent == test_dir.parent:
                return train_dir, test_dir
    return None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", type=Path, default=None, help="dataset whose train split is trained on")
    parser.add_argument("--test-data", type=Path, default=None,
                        help="dataset whose test split is evaluated (default: --data)")
    parser.add_argument("--minutes", type=float, default=10.0, help="training wall-time budget")
    parser.add_argument("--config", default="dotsim/configs/train_tiny.toml")
    parser.add_argument("--train-scenes", type=int, default=100, help="oracle dataset only")
    parser.add_argument("--test-scenes", type=int, default=8, help="oracle dataset only")
    parser.add_argument("--threads", type=int, default=1, help="torch CPU threads (1 is fastest when shared)")
    parser.add_argument("--out", type=Path, default=None, help="keep the run and eval here")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)

    with tempfile.TemporaryDirectory() as tmp:
        work = args.out or Path(tmp)
        if args.data is not None:
            data, test_data = args.data, args.test_data or args.data
            source = f"train split of {data}, test split of {test_data}"
        elif (found := generated_datasets()) is not None:
            data, test_data = found
            source = f"generator output: train split of {data}, test split of {test_data}"
        else:
            data = test_data = make_dataset(work / "oracle_dataset", scenes=args.train_scenes,
                                            frames_per_scene=2, test_scenes=args.test_scenes, seed=7)
            source = (f"oracle-rendered synthetic data (tests/trainer_fixtures.py), {args.train_scenes} "
                      f"train / {args.test_scenes} test scenes x 2 frames; no generator output under out/")
        frames, rig, _ = list_frames(data, "train")
        test_frames, _, _ = list_frames(test_data, "test")
        base = load_config(args.config).to_dict()

        def config(steps: int, epochs: int):
            d = json.loads(json.dumps(base))
            # StepLR halving every epochs // 4 epochs: at 25, 50 and 75 % of the run
            d["train"].update(max_steps=steps, epochs=epochs, lr_step_epochs=max(1, epochs // 4),
                              checkpoint_every=max(steps, 1), image_every=max(steps // 10, 1))
            return config_from_dict(d, args.config)

        # A step's time is the difference of two short runs: one run's time also holds start-up
        # (model, loader, TensorBoard, first-step allocations), which made a 60 min budget train 41 min.
        short, long = (train(config(n, 1000), data, work / f"calibration_{n}", progress=False)["seconds"]
                       for n in (5, 25))
        per_step = max(long - short, 1e-3) / 20
        steps_per_epoch = len(frames) // base["train"]["batch_size"]
        steps = max(10, int(args.minutes * 60 / per_step))
        epochs = max(1, round(steps / steps_per_epoch))
        print(f"data: {source}\n{len(frames)} train / {len(test_frames)} test frames at "
              f"{rig.camera.width}x{rig.camera.height}; "
              f"{per_step:.2f} s/step -> {steps} steps ({epochs} epochs) for {args.minutes:g} min",
              flush=True)
        cfg = config(steps, epochs)
        start = time.perf_counter()
        result = train(cfg, data, work / "run", max_seconds=args.minutes * 60 * 1.1)
        trained_s = time.perf_counter() - start
        rows = evaluate(work / "run" / "checkpoint.pt", test_data, work / "eval", progress=False)
    print(f"\ntrained {result['step']} steps in {trained_s / 60:.1f} min ({args.threads} thread(s)); "
          f"test split:\n")
    print(format_table(rows))
    net = next(r for r in rows if r["method"] == "network" and r["range"] == "all")
    sgbm = next(r for r in rows if r["method"] == "sgbm" and r["range"] == "all")
    ratio = net["o(0.5)"] / sgbm["o(0.5)"] if sgbm["o(0.5)"] else float("inf")
    print(f"summary: o(0.5) network {net['o(0.5)']:.4f} vs SGBM {sgbm['o(0.5)']:.4f} "
          f"(ratio {ratio:.3f}; goal <= 0.5: {'met' if ratio <= 0.5 else 'not met'}); "
          f"o(1) {net['o(1)']:.4f} vs {sgbm['o(1)']:.4f}; trained {trained_s / 60:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
