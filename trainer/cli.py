"""`dotsim train`, `dotsim eval`, `dotsim infer`: the trainer's commands (docs/TRAINER.md)."""

from __future__ import annotations

import argparse
from dataclasses import replace
from functools import partial

from dotsim.command_options import add_no_progress, add_output
from dotsim.dataset import FormatError
from dotsim.frame_source import open_source
from dotsim.option_types import integer, number
from dotsim.output_folder import EVAL, PREDICTIONS, TRAINING_RUN, check_output_folder, removed_if_failed
from trainer.config import ConfigError, load_config
from trainer.samples import DataError

# The trainer's expected errors: one line and exit status 1 (commands.cli.main prints them).
EXPECTED_ERRORS = {ConfigError: 1, DataError: 1, FormatError: 1, FloatingPointError: 1}


def _train(args: argparse.Namespace) -> None:
    from trainer.checkpoint import CHECKPOINT
    from trainer.distributed import run_on_ranks
    from trainer.train import disk_full_in, train

    # before the data is read or a rank started
    check_output_folder(args.out, TRAINING_RUN, "--out", "dotsim train")
    cfg = load_config(args.config)
    if args.max_steps is not None:
        cfg = replace(cfg, train=replace(cfg.train, max_steps=args.max_steps))
    data = open_source(args.data, args.split)
    validation = open_source(args.val_data, args.val_split) if args.val_data is not None else None
    run = train if args.nproc == 1 else partial(run_on_ranks, args.nproc, train)
    # a run that fails before its first checkpoint leaves no tb/ of a run that cannot resume
    with disk_full_in(args.out), removed_if_failed(args.out, lambda out: (out / CHECKPOINT).is_file()):
        run(cfg, data, args.out, resume=args.resume, device=args.device, max_seconds=args.minutes * 60,
            validation=validation, val_frames=args.val_frames, progress_bar=not args.no_progress)


def _eval(args: argparse.Namespace) -> None:
    from trainer.evaluate import evaluate

    check_output_folder(args.out, EVAL, "--out", "dotsim eval")
    validation = open_source(args.val_data, args.val_split) if args.val_data is not None else None
    with removed_if_failed(args.out):  # no errors/ of an eval that wrote no table
        evaluate(args.checkpoint, open_source(args.data, args.split), args.out, device=args.device,
                 max_frames=args.max_frames, images=args.images, precision=args.precision,
                 validation=validation, val_frames=args.val_frames, progress_bar=not args.no_progress)


def _infer(args: argparse.Namespace) -> None:
    from trainer.infer import infer

    check_output_folder(args.out, PREDICTIONS, "--out", "dotsim infer")
    infer(args.checkpoint, args.inputs, args.out, device=args.device, precision=args.precision,
          progress_bar=not args.no_progress)


def _add_inference_device(p: argparse.ArgumentParser) -> None:
    """--device, --precision and --no-progress of eval and infer."""
    from trainer.checkpoint import PRECISIONS

    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="cpu (default) or cuda")
    p.add_argument("--precision", choices=PRECISIONS, default="float32",
                   help="float32 (default), or float16 / bfloat16 autocast (docs/TRAINER.md: their "
                   "disparity differences against float32)")
    add_no_progress(p)


def add_parser(subparsers) -> None:
    p = subparsers.add_parser(
        "train", help="train the GigaDepth branching network on a dotsim dataset",
        description="Train the GigaDepth network (conv backbone + classification tree over the projector "
        "column) on the scenes of --split in DATA. Writes RUN/checkpoint.pt (model, optimiser, schedule, "
        "step, config, rig, RNG states; saved every [train].checkpoint_every steps and at the end) and "
        "TensorBoard logs in RUN/tb (tensorboard --logdir RUN/tb). A CPU run with the same config, data "
        "and seed is deterministic. --nproc N (or torchrun --nproc_per_node N -m commands.cli train ...) "
        "trains with N data-parallel processes (DDP: gloo on CPU, NCCL on CUDA with one GPU each); "
        "[train].batch_size is the global batch, shared out among them, so N processes train as one does.")
    p.add_argument("--config", required=True, metavar="TOML",
                   help="training config: a built-in one's name, e.g. train_tiny (CPU) or train_gigadepth "
                   "(`dotsim config show NAME`), or a TOML file (keys: docs/TRAIN_CONFIG.md)")
    p.add_argument("--data", required=True, metavar="DATA",
                   help="sealed dotsim dataset directory, or its WebDataset shards from `dotsim export`: the "
                   "export folder, a shard, a brace pattern (shards/shard-{000000..000009}.tar) or URLs "
                   "(http(s)://, pipe:; copied once to $DOTSIM_CACHE, default ~/.cache/dotsim); both forms "
                   "give the same run")
    add_output(p, "run directory for checkpoint.pt and tb/", metavar="RUN")
    p.add_argument("--resume", action="store_true",
                   help="continue RUN/checkpoint.pt (same config and rig required); without it an existing "
                   "checkpoint is an error")
    p.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                   help="cpu (default) or cuda; [train].amp sets the precision on either")
    p.add_argument("--split", default="train", help="scene split to train on: train (default), test or all")
    p.add_argument("--nproc", type=integer(1), default=1, metavar="N",
                   help="data-parallel processes on this machine (default 1); each takes batch_size / N "
                   "samples of every batch and the CPU threads are shared out; rank 0 writes and prints")
    p.add_argument("--minutes", type=number(0.0), default=0.0, metavar="M",
                   help="stop (with a checkpoint) after the first step that ends past M minutes of training "
                   "(default 0: run the config's epochs / max_steps)")
    p.add_argument("--max-steps", type=integer(1), default=None, metavar="N",
                   help="stop after optimiser step N (overrides [train].max_steps; a resumed run may "
                   "change it)")
    p.add_argument("--val-data", default=None, metavar="DIR",
                   help="held-out frames to score while training: o(0.5..5) of the network over their valid "
                   "and their solvable pixels every [train].val_every steps and at the end, and an image of "
                   "the first one's error, in TensorBoard (validation/...); never the training frames")
    p.add_argument("--val-split", default="all", help="split of --val-data (default all)")
    p.add_argument("--val-frames", type=integer(1), default=4, metavar="N",
                   help="validation frames, spread over the split (default 4)")
    add_no_progress(p)
    p.set_defaults(func=_train, errors=EXPECTED_ERRORS)

    p = subparsers.add_parser(
        "eval", help="outlier rates o(0.5..5) of a checkpoint and of StereoSGBM, error images",
        description="Evaluate a checkpoint and OpenCV StereoSGBM (IR vs the pattern as seen from infinity, "
        "block 5, P1 200, P2 800; its disparity range reaches the nearest depth of the data's config and GT; "
        "plain and LCN-preprocessed) on the same frames: o(t) = share of valid pixels (pattern visible, "
        "finite GT) whose disparity error exceeds t = 0.5, 1, 2, 5 camera pixels at full resolution (no "
        "estimate, or GT outside a method's range, counts as an outlier), overall and per GT depth range, "
        "then by pixel class (on / off the edge mask, slanted: GT disparity changing over 0.05 px per px, "
        "solvable or not: the 9 x 9 window's pattern against "
        "the sensor noise), which pixels both, only one or neither method get wrong, and the share of "
        "estimates outside the rig's feasible disparity range, with GigaDepth's reference figures and a "
        "one-line verdict against the SGBM variant chosen on --val-data. Writes OUT/eval.md, OUT/eval.csv "
        "and OUT/errors/*.png (IR | network error | SGBM error, with a legend: 0-5 px turbo, outliers "
        "black, no GT grey).")
    p.add_argument("--checkpoint", required=True, metavar="CKPT", help="RUN/checkpoint.pt from dotsim train")
    p.add_argument("--data", required=True, metavar="DIR", help="sealed dotsim dataset with ground truth")
    add_output(p, "folder for eval.md, eval.csv, errors/", metavar="DIR")
    p.add_argument("--split", default="test", help="scene split to evaluate: test (default), train or all")
    p.add_argument("--max-frames", type=integer(0), default=0, metavar="N",
                   help="evaluate the first N frames only (default 0: all)")
    p.add_argument("--images", type=integer(0), default=8, metavar="N",
                   help="error images for the first N frames")
    p.add_argument("--val-data", default=None, metavar="DIR",
                   help="dataset whose --val-split frames choose SGBM's preprocessing (plain or LCN) "
                   "by o(0.5), e.g. the training data (SGBM learns nothing from it), never the evaluated "
                   "frames. Default: none (SGBM plain)")
    p.add_argument("--val-split", default="train", help="split of --val-data (default train)")
    p.add_argument("--val-frames", type=integer(0), default=8, metavar="N",
                   help="validation frames, spread over the split (default 8; 0 = all)")
    _add_inference_device(p)
    p.set_defaults(func=_eval, errors=EXPECTED_ERRORS)

    p = subparsers.add_parser(
        "infer", help="disparity/depth EXR, colour PNG and PLY point cloud from IR frames",
        description="Run a trained checkpoint on IR frames: dotsim frame EXRs (rendered or captured; their "
        "'ir' channel is used) or plain greyscale IR images (8/16-bit PNG, grey or RGB with equal "
        "channels, or EXR) of the checkpoint's camera size. Writes per input NAME.exr (channels "
        "disparity [camera px], depth [m]), NAME.png (colour-mapped disparity) and NAME.ply (points in "
        "metres, camera frame). A half-resolution network's depth edges take the surface whose dots each "
        "pixel's window matches in the pattern the checkpoint keeps, as eval scores them.")
    p.add_argument("--checkpoint", required=True, metavar="CKPT", help="RUN/checkpoint.pt from dotsim train")
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="frame EXR(s) or IR PNG/EXR image(s)")
    add_output(p, "output folder", metavar="DIR")
    _add_inference_device(p)
    p.set_defaults(func=_infer, errors=EXPECTED_ERRORS)
