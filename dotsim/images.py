"""Image files: reading one greyscale image (8/16-bit PNG, another raster OpenCV decodes, or EXR) and
writing PNG/JPEG images atomically.

Patterns (dotsim.patterns.load_pattern), recorded sensor frames (capture.frames.read_image) and
inference inputs (trainer.infer.read_ir) all go through read_grey_image, so they accept the same
files and refuse bad ones with the same messages. Callers add their own checks (size, value range)
and may translate ImageError into their own error class.

One colour rule for everyone: an image with several colour channels is accepted only when they
are identical (tools often save grey as RGB); anything else is refused, because an IR intensity
cannot be recovered from colour without knowing how the colours were made. Alpha is ignored.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dotsim.file_io import atomic_write_bytes, sha256_bytes

# Channel names an EXR's grey image may have, most specific first: dotsim frames and IR tools name
# it ir/IR, OpenEXR's luminance images Y, RGB images repeat grey in R.
EXR_GREY_CHANNELS = ("ir", "IR", "Y", "R")


class ImageError(ValueError):
    """An image file is missing or unusable; the message names the file and the problem."""


@dataclass(frozen=True)
class GreyImage:
    """One decoded greyscale image.

    pixels: (H, W) as stored: uint8, uint16, or float32 for EXR. white_level: the value meaning
    full scale (255, 65535, or 1.0 for EXR). sha256: hex checksum of the file's bytes.
    """

    path: Path
    pixels: np.ndarray
    white_level: float
    sha256: str

    @property
    def shape(self) -> tuple[int, int]:
        return self.pixels.shape

    def relative(self, white_level: float | None = None) -> np.ndarray:
        """Pixels / white level as float64 (white_level None: the format's full scale). float64 so a
        later float16 or float32 is one rounding of the exact value, not a rounding of a rounding."""
        level = self.white_level if white_level is None else white_level
        return self.pixels.astype(np.float64) / level


def read_grey_image(path: str | os.PathLike) -> GreyImage:
    """Decode a greyscale image: EXR by its .exr suffix, anything else with OpenCV (8/16-bit only).

    EXR: the first of EXR_GREY_CHANNELS present, else the only channel, as float32.
    Raises ImageError naming the file for: a missing or unreadable file, an empty file, a file that
    does not decode, an unsupported sample type, an EXR with several channels none of them grey,
    colour channels that differ, no pixels, or NaN/inf values.
    """
    path = Path(path)
    if not path.is_file():
        raise ImageError(f"{path}: {'is a folder, not a file' if path.is_dir() else 'no such file'}")
    try:
        data = path.read_bytes()
    except OSError as error:
        raise ImageError(f"{path}: cannot read ({error.strerror})") from None
    if not data:
        raise ImageError(f"{path}: file is empty")
    if path.suffix.lower() == ".exr":
        pixels, white = _decode_exr(path), 1.0
    else:
        pixels = _decode_raster(path, data)
        white = float(np.iinfo(pixels.dtype).max)
    if pixels.ndim == 3:
        colour = pixels[..., :3]  # an alpha channel says nothing about intensity
        if not all(np.array_equal(colour[..., 0], colour[..., c]) for c in range(1, colour.shape[-1])):
            raise ImageError(f"{path}: colour image (its channels differ); a greyscale image is needed: "
                             "one channel, or colour channels that are all equal")
        pixels = colour[..., 0]
    if pixels.ndim != 2 or pixels.size == 0:
        raise ImageError(f"{path}: expected a non-empty 2-D greyscale image, got shape {pixels.shape}")
    if pixels.dtype == np.float32 and not np.isfinite(pixels).all():
        raise ImageError(f"{path}: image contains {int((~np.isfinite(pixels)).sum())} NaN/inf pixels")
    return GreyImage(path, np.ascontiguousarray(pixels), white, sha256_bytes(data))


def _decode_raster(path: Path, data: bytes) -> np.ndarray:
    import cv2

    pixels = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if pixels is None:
        kind = path.suffix[1:].upper() or "image"
        raise ImageError(f"{path}: not a readable {kind} image (OpenCV could not decode it)")
    if pixels.dtype not in (np.uint8, np.uint16):
        raise ImageError(f"{path}: sample type {pixels.dtype} unsupported; use an 8/16-bit PNG or an EXR")
    return pixels


def _decode_exr(path: Path) -> np.ndarray:
    import OpenEXR  # imported here so users of PNG images only do not need it

    try:
        with OpenEXR.File(str(path), separate_channels=True) as exr:
            channels = {name: channel.pixels for name, channel in exr.parts[0].channels.items()}
    except Exception as error:  # OpenEXR raises bare RuntimeError for every kind of bad file
        raise ImageError(f"{path}: not a readable EXR image ({error})") from None
    for name in EXR_GREY_CHANNELS:
        if name in channels:
            return np.asarray(channels[name], np.float32)
    if len(channels) == 1:
        return np.asarray(next(iter(channels.values())), np.float32)
    raise ImageError(f"{path}: EXR has channels {sorted(channels)}; expected one channel or one named "
                     f"{', '.join(EXR_GREY_CHANNELS)}")


WRITE_SUFFIXES = (".png", ".jpg", ".jpeg")


def write_image(path: str | os.PathLike, image: np.ndarray) -> Path:
    """Encode an 8/16-bit grey or BGR image by the file suffix (.png, .jpg) and write it atomically
    (dotsim.file_io.atomic_write_bytes, which names a missing or read-only folder), so a reader never
    sees half an image."""
    import cv2

    path = Path(path)
    if path.suffix.lower() not in WRITE_SUFFIXES:
        raise ImageError(f"{path}: suffix {path.suffix!r} is not one of {list(WRITE_SUFFIXES)}")
    ok, data = cv2.imencode(path.suffix, image)
    if not ok:
        raise ImageError(f"{path}: OpenCV could not encode a {image.dtype} image of shape {image.shape}")
    return atomic_write_bytes(path, data.tobytes())
