"""Reading recorded sensor frames: find image files, decode them to float, pair projector on/off.

Real IR frames arrive as greyscale 8-bit PNG, 16-bit PNG or single-channel EXR (what OpenNI2,
librealsense and the Structure SDK sample tools save). Everything here is plain numpy + OpenCV +
OpenEXR; no sensor SDK is needed. Values are returned as float32 in "relative exposure" units:
raw value / white level, so a saturated pixel of an integer image reads 1.0, as in the simulator.
"""

from __future__ import annotations

import glob
import hashlib
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

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


@dataclass(frozen=True)
class RawImage:
    """One decoded frame: pixels as stored, the white level that maps to 1.0, and the file's sha256."""

    path: Path
    pixels: np.ndarray  # (H, W) as stored: uint8, uint16 or float32
    white_level: float  # 255, 65535 or 1.0 unless overridden
    sha256: str

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape

    def relative(self, white_level: float | None = None) -> np.ndarray:
        """Pixels / white level as float64 (white_level None: the format's full scale). float64 so the
        dataset's float16 is one rounding of the exact value, not a rounding of a float32 rounding."""
        level = self.white_level if white_level is None else white_level
        return self.pixels.astype(np.float64) / level


def _decode_png(path: Path, data: bytes) -> np.ndarray:
    import cv2

    pixels = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        raise CaptureError(f"{path}: not a readable PNG image")
    if pixels.dtype not in (np.uint8, np.uint16):
        raise CaptureError(f"{path}: PNG sample type {pixels.dtype} unsupported (8- or 16-bit only)")
    return pixels


def _decode_exr(path: Path) -> np.ndarray:
    import OpenEXR

    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = {name: ch.pixels for name, ch in exr.parts[0].channels.items()}
    except Exception as error:  # OpenEXR raises bare RuntimeError for every kind of bad file
        raise CaptureError(f"{path}: not a readable EXR image ({error})") from error
    for name in ("Y", "ir", "IR", "R"):
        if name in channels:
            return np.asarray(channels[name], dtype=np.float32)
    if len(channels) == 1:
        return np.asarray(next(iter(channels.values())), dtype=np.float32)
    raise CaptureError(
        f"{path}: EXR has channels {sorted(channels)}; expected one channel or one named Y, ir or R"
    )


def read_image(path: Path) -> RawImage:
    """Decode one greyscale frame (8/16-bit PNG or EXR) and checksum its file bytes.

    A colour PNG is accepted only when its channels are identical (some tools save grey as RGB).
    Raises CaptureError naming the file for a missing, unreadable, colour, empty or non-finite image.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as error:
        raise CaptureError(f"{path}: cannot read ({error.strerror})") from error
    digest = hashlib.sha256(data).hexdigest()
    if path.suffix.lower() == ".exr":
        pixels, white = _decode_exr(path), 1.0
    else:
        pixels = _decode_png(path, data)
        white = float(np.iinfo(pixels.dtype).max)
    if pixels.ndim == 3:
        colour = pixels[..., :3]  # ignore an alpha channel
        if not all(np.array_equal(colour[..., 0], colour[..., c]) for c in range(1, colour.shape[-1])):
            raise CaptureError(f"{path}: colour image; IR frames must be greyscale (one channel)")
        pixels = colour[..., 0]
    if pixels.ndim != 2 or pixels.size == 0:
        raise CaptureError(f"{path}: expected a 2-D greyscale image, got shape {pixels.shape}")
    if pixels.dtype == np.float32:
        if not np.all(np.isfinite(pixels)):
            raise CaptureError(f"{path}: image holds NaN or infinite values")
        if np.abs(pixels).max() > FLOAT16_MAX:
            raise CaptureError(f"{path}: values exceed {FLOAT16_MAX:g}, the largest half float "
                               f"the dataset format stores")
    return RawImage(path=path, pixels=np.ascontiguousarray(pixels), white_level=white, sha256=digest)


def check_size(image: RawImage, width: int, height: int, rig_name: str) -> None:
    """Raise CaptureError naming the file unless the image is height x width (the rig camera's size)."""
    if image.shape != (height, width):
        raise CaptureError(
            f"{image.path}: image is {image.shape[1]} x {image.shape[0]} px but rig {rig_name!r} "
            f"camera is {width} x {height} px"
        )


def pair_on_off(on_files: list[Path], off_files: list[Path]) -> list[tuple[Path, Path]]:
    """Pair projector-on with projector-off files by natural sort order; counts must be equal.

    Matching by order (not by name) works for the usual layouts: two folders with equal names,
    or one folder with on_000.png / off_000.png. Raises CaptureError giving both counts.
    """
    if len(on_files) != len(off_files):
        raise CaptureError(
            f"{len(on_files)} projector-on frames (first {on_files[0]}) but {len(off_files)} "
            f"projector-off frames (first {off_files[0]}); each on frame needs one off frame"
        )
    overlap = set(on_files) & set(off_files)
    if overlap:
        raise CaptureError(f"{sorted(overlap)[0]} is listed both as projector-on and as projector-off")
    return list(zip(on_files, off_files, strict=True))
