"""Reading recorded sensor frames: find image files, decode them to float, pair projector on/off.

Real IR frames arrive as greyscale 8-bit PNG, 16-bit PNG or single-channel EXR (what OpenNI2,
librealsense and the Structure SDK sample tools save). Everything here is plain numpy + OpenCV +
OpenEXR; no sensor SDK is needed. Values are returned as float32 in "relative exposure" units:
raw value / white level, so a saturated pixel of an integer image reads 1.0, as in the simulator.
"""

from __future__ import annotations

import glob
import re
from pathlib import Path

import numpy as np

from dotsim.images import GreyImage, ImageError, read_grey_image

IMAGE_SUFFIXES = (".png", ".exr")

# The largest finite float16; the dataset stores IR and ambient as half floats.
FLOAT16_MAX = 65504.0


class CaptureError(ValueError):
    """Bad capture input; the message names the file or argument and what is allowed."""


def natural_key(path: Path) -> list:
    """Sort key so that frame_2.png sorts before frame_10.png (digit runs compare as numbers)."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", path.name)]


def list_images(spec: str | Path, *, what: str = "images") -> list[Path]:
    """Image files named by `spec`: a folder (its *.png / *.exr files) or a glob pattern.

    Returns the files in natural sort order. Raises CaptureError naming `spec` when the folder does
    not exist or nothing matches; `what` (e.g. "--on frames") makes the message say which argument.
    """
    spec = str(spec)
    path = Path(spec)
    if path.is_dir():
        files = [p for p in path.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_SUFFIXES]
        if not files:
            raise CaptureError(f"{what}: folder {spec} holds no .png or .exr files")
    elif glob.has_magic(spec):
        files = [Path(p) for p in glob.glob(spec) if Path(p).is_file()]
        if not files:
            raise CaptureError(f"{what}: no files match the pattern {spec}")
        unsupported = [p for p in files if p.suffix.lower() not in IMAGE_SUFFIXES]
        if unsupported:
            raise CaptureError(
                f"{what}: {unsupported[0]} is not a .png or .exr file (pattern {spec} must match images only)"
            )
    elif path.is_file():
        if path.suffix.lower() not in IMAGE_SUFFIXES:
            raise CaptureError(f"{what}: {spec} is not a .png or .exr file")
        files = [path]
    else:
        raise CaptureError(f"{what}: {spec} does not exist (give a folder, an image or a glob pattern)")
    return sorted(files, key=natural_key)


def read_image(path: Path) -> GreyImage:
    """Decode one greyscale frame (8/16-bit PNG or EXR, dotsim.images.read_grey_image) with the
    sha256 of its file bytes.

    Raises CaptureError naming the file for what read_grey_image refuses (missing, unreadable,
    colour, empty, NaN/inf) and for EXR values beyond what the dataset's half floats hold.
    """
    try:
        image = read_grey_image(path)
    except ImageError as error:
        raise CaptureError(str(error)) from None
    if image.pixels.dtype == np.float32 and np.abs(image.pixels).max() > FLOAT16_MAX:
        raise CaptureError(f"{path}: values exceed {FLOAT16_MAX:g}, the largest half float "
                           f"the dataset format stores")
    return image


def check_size(image: GreyImage, width: int, height: int, rig_name: str) -> None:
    """Raise CaptureError naming the file unless the image is height x width (the rig camera's size)."""
    if image.shape != (height, width):
        raise CaptureError(
            f"{image.path}: image is {image.shape[1]} x {image.shape[0]} px but rig {rig_name!r} "
            f"camera is {width} x {height} px"
        )


def pair_on_off(on_files: list[Path], off_files: list[Path],
                right_files: list[Path] | None = None) -> list[tuple[Path, ...]]:
    """Pair projector-on with projector-off files (and, for a stereo pair, the right camera's
    projector-on files) by natural sort order; counts must be equal.

    Matching by order (not by name) works for the usual layouts: two folders with equal names,
    or one folder with on_000.png / off_000.png. Raises CaptureError giving both counts, or naming a
    file listed twice.
    """
    lists = {"projector-on": on_files, "projector-off": off_files}
    if right_files is not None:
        lists["right projector-on"] = right_files
    (first, first_files), *others = lists.items()
    for name, files in others:
        if len(files) != len(first_files):
            raise CaptureError(f"{len(first_files)} {first} frames (first {first_files[0]}) but {len(files)} "
                               f"{name} frames (first {files[0]}); each on frame needs one {name} frame")
    roles = [(path, name) for name, files in lists.items() for path in files]
    seen: dict[Path, str] = {}
    for path, name in roles:
        if path in seen:
            raise CaptureError(f"{path} is listed both as {seen[path]} and as {name}")
        seen[path] = name
    return list(zip(*lists.values(), strict=True))


def recorded_images(dataset_dir: Path, channel: str) -> list[GreyImage]:
    """One channel ("ir" or "ambient") of every frame of a recorded dataset (`capture record`), as
    float32 images at white level 1 with the frame file's sha256; CaptureError when a scene lacks it."""
    from dotsim import dataset

    images = []
    for ref in dataset.open_dataset(dataset_dir).scenes:
        scene = dataset.read_scene(ref.path)
        if channel not in scene.meta["channels"]:
            raise CaptureError(f"{ref.path}: has no {channel!r} channel (channels "
                               f"{list(scene.meta['channels'])})")
        for entry, frame in zip(scene.meta["frames"], scene.frames, strict=True):
            images.append(GreyImage(ref.path / entry["file"], frame[channel].astype(np.float32), 1.0,
                                    entry["sha256"]))
    return images
