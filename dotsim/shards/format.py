"""The WebDataset sample format of `dotsim export`: member names, channel codecs, versions.

One module for both sides: dotsim/shards/writer.py writes samples with `encode_channel`,
dotsim/shards/reader.py reads them with `decode_channel`, so a codec is defined once. A sample is
one frame; its members are named KEY.EXT (the WebDataset convention), KEY = scene_SSSSSSS_frame_K.
Format 2.0 stores each channel in the first codec of this list that holds it:

- ``CHANNEL.png``: a PNG of integer codes, which every image tool opens, decoded as the sample's
  frame.json `encoding` entry says. Masks: a 1-bit PNG (nonzero = 1). The IR images (`ir`,
  `ir_right`): a 16-bit PNG of the sensor's codes k = ir * (2^bits - 1), used only where that gives
  back the stored float16 bit for bit (generated frames: always). `projector_column` with precision
  "training": a 16-bit PNG of round((column - offset) / step) + 1, 0 where the column is nan or
  outside the codes' range (such pixels never see the pattern: docs/FORMAT.md), step 1/16 projector
  px for projectors up to 3967 px wide (coarser, by powers of two, for wider ones).
- ``CHANNEL.npy.gz``: the array `dotsim.dataset.read_frame` returns, as .npy, gzip-compressed
  (lossless; the webdataset library decompresses .gz members itself).

Format 1.0 stored every channel as plain ``CHANNEL.npy`` and the scene's metadata in every sample;
2.0 stores ``scene.json.gz`` once per scene and shard (in the scene's first sample there; each
frame.json carries the rig and pattern), never the channels derived on read (`disparity`,
`stereo_disparity`), and any channel subset the exporter chose.
"""

from __future__ import annotations

import gzip
import io

import numpy as np

from dotsim.channels import CHANNEL
from dotsim.dataset import FormatError, scene_name

WEBDATASET_FORMAT = "dotsim-webdataset"
WEBDATASET_VERSION = "2.0"
INDEX_NAME = "index.json"
SUMS_NAME = "SHA256SUMS"
PATTERN_NAME = "pattern.png"
PRECISIONS = ("exact", "training")
# The float16 IR of a generated frame is a code of the sensor's bit depth; these are tried when the
# scene's config does not name one (captures of 8- to 16-bit sensors).
IR_BITS = (8, 10, 12, 16)
COLUMN_MARGIN = 64.0  # projector px kept on either side of the pattern by the training codec
COLUMN_FINEST_STEP = 1 / 16


def sample_key(scene_index: int, frame_index: int) -> str:
    """The sample's WebDataset key (also `dotsim infer`'s output name for that frame)."""
    return f"{scene_name(scene_index)}_frame_{frame_index}"


def check_version(version, where) -> None:
    """FormatError unless `version` is a 1.x or 2.x export (the major versions this reader knows)."""
    major = str(version).split(".")[0]
    if major not in ("1", "2"):
        raise FormatError(f"{where}: export format_version {version!r} is not supported (this dotsim "
                          f"reads 1.x and 2.x); upgrade dotsim")


def _png(codes: np.ndarray, bilevel: bool = False) -> bytes:
    import cv2

    params = [cv2.IMWRITE_PNG_COMPRESSION, 9]
    # Noisy IR codes compress best with Huffman coding alone (280 against 300 KB per 608 x 448
    # frame with the default strategy, measured on `make dataset` frames); masks as 1 bit a pixel.
    params += [cv2.IMWRITE_PNG_BILEVEL, 1] if bilevel else [cv2.IMWRITE_PNG_STRATEGY,
                                                           cv2.IMWRITE_PNG_STRATEGY_HUFFMAN_ONLY]
    ok, data = cv2.imencode(".png", codes, params)
    if not ok:
        raise ValueError("PNG encoding failed")
    return data.tobytes()


def _unpng(data: bytes, where: str) -> np.ndarray:
    import cv2

    image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.ndim != 2:
        raise FormatError(f"{where}: not a readable single-channel PNG")
    return image


def npy_gz_bytes(array: np.ndarray) -> bytes:
    """gzip of the .npy of `array` (mtime 0: the same array gives the same bytes)."""
    stream = io.BytesIO()
    np.save(stream, np.ascontiguousarray(array), allow_pickle=False)
    return gzip.compress(stream.getvalue(), compresslevel=6, mtime=0)


def column_codec(projector_width: int) -> dict:
    """The training codec of `projector_column` for a projector this wide: {step, offset}, so that
    column = (code - 1) * step + offset for codes 1 .. 65535 (0: nan).

    >>> column_codec(3072)
    {'step': 0.0625, 'offset': -64.0}
    >>> column_codec(6000)["step"]
    0.125
    """
    step = COLUMN_FINEST_STEP
    while (projector_width + 2 * COLUMN_MARGIN) / step > 65534:
        step *= 2
    return {"step": step, "offset": -COLUMN_MARGIN}


def _ir_codes(ir: np.ndarray, bits: list[int]) -> tuple[np.ndarray, int] | None:
    """(codes, bits) for the first bit depth whose codes decode to `ir` exactly, else None."""
    values = ir.astype(np.float64)
    for b in bits:
        full = 2**b - 1
        codes = np.round(values * full)
        if codes.min(initial=0) >= 0 and codes.max(initial=0) <= full:
            codes = codes.astype(np.uint16)
            if np.array_equal(decode_ir(codes, b), ir):
                return codes, b
    return None


def decode_ir(codes: np.ndarray, bits: int) -> np.ndarray:
    """float16 IR from sensor codes, as the generator stores it (code / (2^bits - 1))."""
    return (codes.astype(np.float32) / np.float32(2**bits - 1)).astype(np.float16)


def encode_channel(name: str, array: np.ndarray, precision: str, projector_width: int,
                   bit_depth: int | None = None) -> tuple[str, bytes, dict | None]:
    """(member extension, bytes, frame.json encoding entry or None) of one channel of a frame.

    precision "exact" keeps every value (masks and IR codes as PNG, the rest as .npy.gz);
    "training" also stores projector_column as fixed-point PNG (column_codec)."""
    if CHANNEL[name].source == "mask":
        return "png", _png(array.astype(np.uint8), bilevel=True), {"codec": "mask"}
    if CHANNEL[name].source == "sensor model":  # ir, ir_right: sensor codes
        found = _ir_codes(array, ([bit_depth] if bit_depth else []) + [b for b in IR_BITS if b != bit_depth])
        if found is not None:
            return "png", _png(found[0]), {"codec": "ir_codes", "bits": found[1]}
    if name == "projector_column" and precision == "training":
        codec = column_codec(projector_width)
        codes = np.round((array.astype(np.float64) - codec["offset"]) / codec["step"]) + 1
        codes = np.where(np.isfinite(codes) & (codes >= 1) & (codes <= 65535), codes, 0).astype(np.uint16)
        return "png", _png(codes), {"codec": "fixed_point", **codec}
    return "npy.gz", npy_gz_bytes(array), None


def decode_channel(name: str, ext: str, data: bytes, encoding: dict | None, where: str) -> np.ndarray:
    """The array of one stored channel member (any format version), as read_frame returns it."""
    if ext == "npy":  # format 1.0
        return np.load(io.BytesIO(data), allow_pickle=False)
    if ext == "npy.gz":
        try:
            return np.load(io.BytesIO(gzip.decompress(data)), allow_pickle=False)
        except (OSError, EOFError, ValueError) as e:
            raise FormatError(f"{where}: channel {name!r} is not a readable .npy.gz ({e})") from None
    codec = (encoding or {}).get("codec")
    image = _unpng(data, f"{where}: channel {name!r}")
    if codec == "mask":
        return (image > 0).astype(np.uint8)
    if codec == "ir_codes":
        return decode_ir(image, int(encoding["bits"]))
    if codec == "fixed_point":
        column = (image.astype(np.float64) - 1) * encoding["step"] + encoding["offset"]
        return np.where(image > 0, column, np.nan).astype(np.float32)
    raise FormatError(f"{where}: channel {name!r} is a PNG without a known encoding in frame.json "
                      f"(got {encoding!r})")


def channel_member(files: dict, name: str) -> str | None:
    """The extension under which a sample's files hold channel `name`, or None."""
    return next((ext for ext in (f"{name}.png", f"{name}.npy.gz", f"{name}.npy") if ext in files), None)
