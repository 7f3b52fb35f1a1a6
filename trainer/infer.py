"""Inference on rendered or captured frames: disparity and depth EXR, a colour PNG, a PLY point cloud.

Inputs: dotsim frame EXRs (their `ir` channel; rendered or captured with `dotsim capture`), or plain IR
images (8/16-bit PNG scaled to [0, 1], or a single-channel EXR) of the checkpoint's camera size.
Outputs per input, named after it (dotsim.prediction_file): NAME.exr (float32 channels disparity
[camera px] and depth [m], nan where no estimate; a stride-2 network's depth edges matched against the
pattern its checkpoint stores, as eval scores them: trainer.upsampling.pattern_guided_disparity; marked
in its header as a prediction of this checkpoint for this input), NAME.png (disparity, turbo colour map
over its 1st..99th percentile, black = none, with a legend under it), NAME.ply (dotsim.pointcloud:
binary, through trimesh; x, y, z in metres in the OpenCV camera frame, IR grey as red/green/blue; only depths
within the rig's max_depth).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dotsim.dataset import FormatError, read_frame
from dotsim.false_colour import colourise, with_legend
from dotsim.file_io import make_folder
from dotsim.images import ImageError, read_grey_image, write_image
from dotsim.pointcloud import depth_points, grey_levels, write_ply
from dotsim.prediction_file import output_name, write_prediction
from dotsim.rig.geometry import Rig
from trainer.checkpoint import load_model, predict_disparity, stored_reference
from trainer.samples import DataError


def read_ir(path: str | Path, rig: Rig) -> np.ndarray:
    """IR image (H, W) float32 in [0, 1] units from a dotsim frame EXR (its `ir` channel, checked
    against scene.json when beside one) or a plain greyscale image (dotsim.images.read_grey_image:
    PNG scaled by its bit depth, EXR as stored); errors name the file."""
    path = Path(path)
    if path.suffix.lower() not in (".exr", ".png"):
        raise DataError(f"{path}: unsupported input {path.suffix!r}; give a frame .exr, an IR .exr or a .png")
    ir = None
    if path.suffix.lower() == ".exr":
        try:
            ir = read_frame(path, channels=("ir",))["ir"]
        except FormatError:
            pass  # not a dotsim frame: read it as a plain IR image below
    if ir is None:
        try:
            ir = read_grey_image(path).relative()
        except ImageError as error:
            raise DataError(str(error)) from None
    expected = (rig.camera.height, rig.camera.width)
    if ir.shape != expected:
        raise DataError(f"{path}: image is {ir.shape[1]}x{ir.shape[0]}, the checkpoint's camera "
                        f"({rig.name}) is {expected[1]}x{expected[0]}")
    return np.asarray(ir, np.float32)


DISPARITY_SWATCHES = (((0, 0, 0), "black: no estimate"),)


def infer(checkpoint: str | Path, inputs: list[str | Path], out_dir: str | Path, device: str = "cpu",
          progress: bool = True, precision: str = "float32", progress_bar: bool = True) -> list[Path]:
    """Run the network on each input in `precision` (trainer.checkpoint.PRECISIONS); returns the written
    EXR paths (PNG and PLY lie beside them). progress: say what was written, with a progress bar
    (progress_bar=False: without)."""
    model, _, rig = load_model(checkpoint, device)
    irs = [read_ir(p, rig) for p in inputs]  # all inputs checked before anything is written
    reference = None
    if model.cfg.stride == 2:  # only a half-resolution output has pixels between samples to choose
        reference = stored_reference(checkpoint, rig)
        if reference is None and progress:
            print(f"{checkpoint}: stores no pattern (saved before checkpoints did, or trained on data "
                  "without one here), so depth edges take the farther sample, not the surface the pattern "
                  "matches", file=sys.stderr)
    names = [output_name(Path(p)) for p in inputs]
    if len(set(names)) != len(names):
        raise DataError(f"inputs {list(map(str, inputs))} give clashing output names {names}")
    out_dir = make_folder(out_dir)
    written = []
    todo = list(zip(names, irs, inputs, strict=True))
    for name, ir, path in tqdm(todo, desc="infer", unit="frame", disable=not (progress and progress_bar)):
        disparity, depth = predict_disparity(model, rig, ir, device, precision, reference)
        write_prediction(out_dir / f"{name}.exr", {"disparity": disparity, "depth": depth},
                         {"checkpoint": str(Path(checkpoint).resolve()), "input": str(Path(path).resolve()),
                          "precision": precision})
        finite = np.isfinite(disparity)
        lo, hi = np.percentile(disparity[finite], [1, 99]) if finite.any() else (0.0, 1.0)
        write_image(out_dir / f"{name}.png", with_legend(colourise(disparity, lo, hi), lo, hi,
                                                         "px disparity (near = high)", DISPARITY_SWATCHES))
        # the rig's range is what the network was trained on: a column at (or past) the pattern's
        # position at infinity gives depths of hundreds of metres that would dwarf the scene
        write_ply(out_dir / f"{name}.ply", *depth_points(depth, rig.camera, grey_levels(ir), rig.max_depth))
        written.append(out_dir / f"{name}.exr")
    if progress:
        print(f"wrote disparity/depth EXR, PNG and PLY for {len(written)} frame(s) to {out_dir}")
    return written
