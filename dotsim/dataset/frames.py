"""Frame files: one scanline OpenEXR per frame, one channel per stored pass.

The channels of the IR camera share one part (a single-part file when that is all a frame has); the
channels of another camera (dotsim.channels.CAMERAS: the colour camera's `rgb`) have their own image
size and lie in a part of their own named after the camera, an (H, W, C) channel as the EXR channels
NAME.R, NAME.G, NAME.B (its components).

FRAME_CHANNELS gives each channel's dtype as read (why each: docs/FORMAT.md). write_frame_file
validates and converts a frame dict and writes it; decode_frame checks a file's channels, shapes
and pixel types and returns them. Format 2.x stores no `disparity` (nor, 2.1 on, `stereo_disparity`):
each is one division of depth (DERIVATIONS), so the writer checks a given one and the reader computes
it from `depth` and the rig the header carries (DERIVED_CHANNELS); format 1.x files store
`disparity` and are read as they are. A file records the oldest format version that has all of its
channels (frame_format_version).
"""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np

from dotsim.channels import (
    CAMERAS,
    CHANNEL,
    CHANNELS,
    DERIVED_CHANNELS,
    LABEL_CHANNELS,
    MASK_CHANNELS,
    OWN_SHAPE_CHANNELS,
    RENDERED_CHANNELS,
    stored_channels,
)
from dotsim.dataset.layout import FormatError, check_format_version
from dotsim.file_io import atomic_write_bytes, sha256_bytes
from dotsim.rig.geometry import Rig, depth_to_disparity, is_ground_truth
from dotsim.rig.stereo import stereo_disparity

# The lossless compressions a dataset's frames may have ([output] exr_compression -> OpenEXR's name).
# zstd, the default, is the smallest and the fastest to read of OpenEXR's lossless codecs on rendered
# frames (zstd over byte-shuffled blocks: float32 ground truth shrinks to 40% of ZIP's size) and needs
# OpenEXR >= 3.4 to read; zip and piz are read by older OpenEXR versions too. Measured in
# docs/FORMAT.md "Compression" (bench.generate_stages --compression, bench.exr_readability).
EXR_COMPRESSIONS = {"zstd": "ZSTD_COMPRESSION", "zip": "ZIP_COMPRESSION", "piz": "PIZ_COMPRESSION"}
EXR_COMPRESSION = EXR_COMPRESSIONS["zstd"]
VERSION_ATTRIBUTE = "dotsim_format_version"
# Format 2.x: the rig (Rig.to_dict() as JSON) the derived channels are computed with.
RIG_ATTRIBUTE = "dotsim_rig"

# Dtype per channel as read (what read_frame returns), from the one declaration of the channels
# (dotsim.channels). Why each was chosen: docs/FORMAT.md. Masks are uint8 in memory and UINT
# (32-bit) in the EXR: EXR has no 8-bit pixel type. Labels are UINT too (lossless), read as int32 (torch
# has no uint32 arithmetic).
FRAME_CHANNELS: dict[str, np.dtype] = {c.name: c.dtype for c in CHANNELS}
# How far (relative) a writer's own derived channel may lie from what format 2.x computes on read
# (DERIVED_CHANNELS): float32 rounding of depth and result.
DERIVED_TOLERANCE = 1e-6


def ground_truth_disparity(depth: np.ndarray, rig: Rig) -> np.ndarray:
    """The stored `disparity` of a frame: fx * b / depth (float32,
    dotsim.rig.geometry.depth_to_disparity), nan where depth is not ground truth (inf or beyond
    rig.max_depth: dotsim.rig.geometry.is_ground_truth). The generator's and the reader's one
    formula, so a derived channel is bit for bit what format 1.x stored."""
    depth = np.asarray(depth, np.float32)
    return depth_to_disparity(np.where(is_ground_truth(depth, rig.max_depth), depth, np.nan), rig)


# Each derived channel from a frame's stored depth and its rig: the generator's and the reader's one
# formula, so what the reader derives is bit for bit what a writer would have stored.
DERIVATIONS = {"disparity": ground_truth_disparity, "stereo_disparity": stereo_disparity}
# The oldest version a 2.x writer records (2.0: ZSTD frames, disparity derived).
OLDEST_WRITTEN = "2.0"


def derivable_channels(stored, has_depth: bool) -> list[str]:
    """The derived channels (DERIVATIONS) a frame storing `stored` gives on read: none without a depth
    to derive them from (`has_depth`); the stereo ones only where the frame stores a channel of the
    stereo pair (a rig may have a second camera its frames did not use).

    >>> derivable_channels(["ir", "depth"], True), derivable_channels(["ir", "ir_right"], True)
    (['disparity'], ['disparity', 'stereo_disparity'])
    """
    pair = any(CHANNEL[c].stereo for c in stored if c in CHANNEL)
    return [c for c in DERIVED_CHANNELS if c not in stored and has_depth and (pair or not CHANNEL[c].stereo)]


def frame_format_version(channels) -> str:
    """The format version a frame file and its scene.json record: the oldest (from OLDEST_WRITTEN up
    to dotsim.dataset.FORMAT_VERSION) that has every one of `channels` (dotsim.channels' `since`), so a scene
    without the channels a later minor added is byte for byte what that older version wrote."""
    def key(version: str) -> tuple[int, ...]:
        return tuple(int(part) for part in version.split("."))
    return max([OLDEST_WRITTEN, *(CHANNEL[name].since for name in channels)], key=key)


def camera_shapes(shape) -> dict[str, tuple[int, int]]:
    """{camera: (height, width)} of a frame's cameras (dotsim.channels.CAMERAS) from `shape`: such a
    dict, or the IR camera's (height, width) alone (a frame of that camera's channels only).

    >>> camera_shapes((4, 6)), camera_shapes({"ir": (4, 6), "colour": (2, 3)})["colour"]
    ({'ir': (4, 6)}, (2, 3))
    """
    if isinstance(shape, dict):
        return {camera: tuple(size) for camera, size in shape.items()}
    return {"ir": tuple(shape)}


def _channel_shape(name: str, shapes: dict, where: str) -> tuple[int, ...]:
    """The shape channel `name`'s arrays have: its camera's (height, width) and its components."""
    channel = CHANNEL[name]
    if channel.camera not in shapes:
        raise FormatError(f"{where}: channel {name!r} is an image of the {channel.camera} camera, whose size "
                          f"the scene does not give ({CAMERAS[channel.camera]})")
    return shapes[channel.camera] + channel.shape_suffix


def _to_stored(name: str, array, where: str) -> np.ndarray:
    """Convert a caller's array to the stored dtype of channel `name`, refusing lossy surprises."""
    a = np.asarray(array)
    dtype = FRAME_CHANNELS[name]
    dims = 2 + len(CHANNEL[name].shape_suffix)
    if a.ndim != dims:
        layout = "(H, W)" if dims == 2 else f"(H, W, {len(CHANNEL[name].components)})"
        raise FormatError(f"{where}: channel {name!r} must be {dims}-D {layout}, found shape {a.shape}")
    if name in MASK_CHANNELS:
        if a.dtype == bool:
            return a.astype(np.uint32)
        if not np.issubdtype(a.dtype, np.integer) or not np.isin(a, (0, 1)).all():
            raise FormatError(f"{where}: mask channel {name!r} must be bool or integers 0/1, "
                              f"found dtype {a.dtype} with values outside {{0, 1}}")
        return a.astype(np.uint32)
    if name in LABEL_CHANNELS:
        integers = np.issubdtype(a.dtype, np.integer)
        if not integers or a.size and (a.min() < 0 or a.max() > np.iinfo(np.int32).max):
            raise FormatError(f"{where}: label channel {name!r} must hold integers 0 to 2^31 - 1, found "
                              f"dtype {a.dtype}" + (f" with values {a.min()}..{a.max()}" if a.size else ""))
        return a.astype(np.uint32)
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise FormatError(f"{where}: channel {name!r} must be numeric, found dtype {a.dtype}")
    with np.errstate(over="ignore"):  # overflow is reported below, naming the channel
        stored = a.astype(dtype, copy=False)
    # Only a conversion can overflow (an array already of the stored type is taken as it is).
    overflow = None if stored is a else np.isfinite(a) & ~np.isfinite(stored)
    if overflow is not None and overflow.any():
        raise FormatError(f"{where}: channel {name!r} has {int(overflow.sum())} finite values beyond "
                          f"the {dtype} range (max {float(np.nanmax(np.abs(a)))}; {dtype} max "
                          f"{float(np.finfo(dtype).max)})")
    if name == "depth":
        bad = np.isnan(stored) | (stored <= 0)
        if bad.any():
            raise FormatError(f"{where}: depth must be > 0 metres or +inf (no hit); {int(bad.sum())} "
                              f"pixels are NaN or <= 0")
    return stored


def _frame_pixels(frame: dict, channels: tuple[str, ...], shapes: dict, where: str,
                  rig: Rig | None) -> dict:
    """Validate a frame dict and convert it to {channel: contiguous array in EXR pixel dtype}: the
    stored channels of `channels`; a derived one the frame carries must match what the reader
    derives (so nothing given is lost unnoticed)."""
    stored = stored_channels(channels)
    missing = [c for c in stored if c not in frame]
    unknown = [c for c in frame if c not in FRAME_CHANNELS]
    if missing:
        raise FormatError(f"{where}: missing channel(s) {missing}; required: {list(stored)}")
    if unknown:
        raise FormatError(f"{where}: unknown channel(s) {unknown}; known: {list(FRAME_CHANNELS)}")
    extra = [c for c in frame if c not in channels]
    if extra:
        raise FormatError(f"{where}: channel(s) {extra} not in this scene's channel list {list(channels)}")
    pixels = {}
    for name in stored:
        array = _to_stored(name, frame[name], where)
        shape = _channel_shape(name, shapes, where)
        if array.shape != shape:
            layout = "height, width, components" if len(shape) > 2 else "height, width"
            raise FormatError(f"{where}: channel {name!r} has shape {array.shape}, the "
                              f"{CHANNEL[name].camera} camera's is {shape} ({layout})")
        pixels[name] = np.ascontiguousarray(array)
    for name in (c for c in channels if c in DERIVED_CHANNELS):
        if "depth" not in channels or rig is None:
            raise FormatError(f"{where}: channel {name!r} is derived from 'depth' and the rig: the "
                              f"channel list must include 'depth' and the rig must be given")
        try:
            derived = DERIVATIONS[name](pixels["depth"], rig)
        except ValueError as error:  # a stereo channel of a rig without a stereo pair
            raise FormatError(f"{where}: channel {name!r}: {error}") from None
        # One computed from depth before its rounding to float32 differs by that rounding alone.
        if name in frame and not np.allclose(_to_stored(name, frame[name], where), derived,
                                             rtol=DERIVED_TOLERANCE, atol=0.0, equal_nan=True):
            raise FormatError(f"{where}: channel {name!r} differs from what the reader derives from its "
                              f"'depth' channel and the rig (fx * baseline / depth, nan beyond "
                              f"rig.max_depth; relative tolerance {DERIVED_TOLERANCE}); leave it out or "
                              f"pass that")
    return pixels


def encode_frame(frame: dict, shape, channels: tuple[str, ...] | None = None,
                 compression: str = EXR_COMPRESSION, where: str = "frame",
                 rig: dict | None = None) -> bytes:
    """The bytes of one frame EXR (validated and converted to the stored dtypes first).

    shape: the IR camera's (height, width), or {camera: (height, width)} (camera_shapes) when the frame
    has channels of another camera (the colour camera's `rgb`), which then lie in a part of their own.
    channels: the channel set the frame must carry (default RENDERED_CHANNELS; the derived ones,
    DERIVED_CHANNELS, may be left out); compression: an OpenEXR compression name (docs/FORMAT.md
    and bench/read_shards.py compare them); rig: the scene's Rig.to_dict(), stored in the header
    for the derived channels (needed when channels has one).
    """
    import OpenEXR

    channels = RENDERED_CHANNELS if channels is None else tuple(channels)
    derives = any(c in DERIVED_CHANNELS for c in channels)
    parsed = _parse_rig(rig, where) if rig is not None and derives else None
    pixels = _frame_pixels(frame, channels, camera_shapes(shape), where, parsed)
    header = {"compression": getattr(OpenEXR, compression), "type": OpenEXR.scanlineimage,
              VERSION_ATTRIBUTE: frame_format_version(channels)}
    if parsed is not None:
        header[RIG_ATTRIBUTE] = json.dumps(rig, sort_keys=True)
    own = {name: pixels.pop(name) for name in OWN_SHAPE_CHANNELS if name in pixels}
    stream = io.BytesIO()
    if not own:  # a single-part file, byte for byte what format 2.2 and before wrote
        OpenEXR.File(header, pixels).write(stream)
        return stream.getvalue()
    parts = [OpenEXR.Part(header, pixels, "ir")]
    for camera in dict.fromkeys(CHANNEL[name].camera for name in own):
        # every part of a multi-part file shares the first one's display window (OpenEXR's rule); its
        # data window is the camera's own image
        part_header = {"compression": header["compression"], "type": OpenEXR.scanlineimage,
                       "displayWindow": parts[0].header["displayWindow"]}
        part_pixels = {f"{name}.{component}": np.ascontiguousarray(own[name][..., k])
                       for name in own if CHANNEL[name].camera == camera
                       for k, component in enumerate(CHANNEL[name].components or "Y")}
        parts.append(OpenEXR.Part(part_header, part_pixels, camera))
    OpenEXR.File(parts).write(stream)
    return stream.getvalue()


def _own_part_channels(parts, path: Path) -> dict[str, np.ndarray]:
    """{channel: (H, W[, C]) array} of the parts after the first (the channels of a camera of their own):
    NAME.COMPONENT EXR channels stacked in the order of the channel's components."""
    found: dict[str, dict[str, np.ndarray]] = {}
    for part in parts[1:]:
        for key, channel in part.channels.items():
            name, _, component = key.rpartition(".")
            if name not in OWN_SHAPE_CHANNELS:
                raise FormatError(f"{path}: part {part.name()!r} holds {key!r}, no channel of a camera of "
                                  f"its own; known: {list(OWN_SHAPE_CHANNELS)}")
            found.setdefault(name, {})[component] = channel.pixels
    out = {}
    for name, components in found.items():
        want = CHANNEL[name].components or "Y"
        if sorted(components) != sorted(want):
            raise FormatError(f"{path}: channel {name!r} stored with components {sorted(components)}, "
                              f"expected {list(want)}")
        stacked = [components[c] for c in want]
        out[name] = np.stack(stacked, axis=-1) if CHANNEL[name].components else stacked[0]
    return out


def _parse_rig(rig: dict, where) -> Rig:
    try:
        return Rig.from_dict(rig)
    except (ValueError, TypeError) as e:
        raise FormatError(f"{where}: rig is not a valid Rig.to_dict() ({e})") from None


def write_frame_file(path: str | os.PathLike, frame: dict, shape: tuple[int, int],
                     channels: tuple[str, ...] | None = None, compression: str = EXR_COMPRESSION,
                     where: str = "frame", rig: dict | None = None) -> str:
    """Write one frame EXR at `path` atomically (encode_frame); return its sha256."""
    data = encode_frame(frame, shape, channels, compression, where, rig)
    atomic_write_bytes(path, data)
    return sha256_bytes(data)


def decode_frame(data: bytes, path: Path, channels=None, shape=None) -> dict[str, np.ndarray]:
    """Decode the bytes of frame file `path` -> {channel: array in its FRAME_CHANNELS dtype}.

    channels: the ones to return, all required (None: every dotsim channel in the file, and in
    format 2.x the derived ones its header allows); shape: (height, width) every channel of the IR
    camera must have, or {camera: (height, width)} (camera_shapes) for the channels of each camera
    (None: all of one camera of one shape). FormatError naming the file.
    """
    import OpenEXR

    try:
        exr = OpenEXR.File(io.BytesIO(data), separate_channels=True)
        # A truncated file opens with no parts; header() then raises a ValueError naming no file.
        header, stored = exr.header(), dict(exr.channels())
        own = _own_part_channels(exr.parts, path)
    except FormatError:
        raise
    except Exception as e:  # OpenEXR raises plain RuntimeError/ValueError for corrupt files
        raise FormatError(f"{path}: not a readable OpenEXR file ({e})") from None
    shapes = {} if shape is None else camera_shapes(shape)
    version = header.get(VERSION_ATTRIBUTE)
    if version is not None:
        check_format_version(version, path)
    rig = header.get(RIG_ATTRIBUTE)
    # Derivable here: format 2.x files with depth and the rig (1.x files store every channel).
    derivable = derivable_channels(stored, rig is not None and "depth" in stored)
    source = "height, width of the rig camera in scene.json"
    if channels is None:
        channels = [c for c in FRAME_CHANNELS if c in stored or c in derivable or c in own]
        if not channels:
            raise FormatError(f"{path}: no dotsim channel found (has {sorted(stored)}; "
                              f"known: {list(FRAME_CHANNELS)})")
    missing = [c for c in channels if c not in stored and c not in derivable and c not in own]
    if missing:
        raise FormatError(f"{path}: missing channel(s) {missing}; file has {sorted([*stored, *own])}")
    out = {}
    for name in channels:
        if name not in FRAME_CHANNELS:
            raise FormatError(f"{path}: unknown channel {name!r}; known: {list(FRAME_CHANNELS)}")
        if name in own:
            out[name] = _own_shape_channel(name, own[name], shapes, path)
            continue
        a = stored[name].pixels if name in stored else stored["depth"].pixels
        shape = shapes.get("ir")
        if shape is None:
            shape, source = a.shape, f"the shape of channel {name!r}"
            shapes["ir"] = shape
        if a.shape != tuple(shape):
            raise FormatError(f"{path}: channel {name!r} has shape {a.shape}, expected {tuple(shape)} "
                              f"({source})")
        if name not in stored:
            out[name] = _derived(name, a, rig, path)
            continue
        want = FRAME_CHANNELS[name]
        if name in MASK_CHANNELS:
            if a.dtype != np.uint32:
                raise FormatError(f"{path}: mask channel {name!r} stored as {a.dtype}, expected UINT")
            if a.max(initial=0) > 1:
                raise FormatError(f"{path}: mask channel {name!r} has values other than 0/1")
            a = a.astype(np.uint8)
        elif name in LABEL_CHANNELS:
            if a.dtype != np.uint32:
                raise FormatError(f"{path}: label channel {name!r} stored as {a.dtype}, expected UINT")
            if a.max(initial=0) > np.iinfo(np.int32).max:
                raise FormatError(f"{path}: label channel {name!r} has values beyond 2^31 - 1")
            a = a.astype(np.int32)
        elif a.dtype != want:
            raise FormatError(f"{path}: channel {name!r} stored as {a.dtype}, expected {want}")
        out[name] = a
    return out


def _own_shape_channel(name: str, a: np.ndarray, shapes: dict, path: Path) -> np.ndarray:
    """A channel of a camera of its own (its own part), checked against that camera's size when known."""
    camera = CHANNEL[name].camera
    if camera in shapes and a.shape != shapes[camera] + CHANNEL[name].shape_suffix:
        raise FormatError(f"{path}: channel {name!r} has shape {a.shape}, expected "
                          f"{shapes[camera] + CHANNEL[name].shape_suffix} ({CAMERAS[camera]})")
    if a.dtype != FRAME_CHANNELS[name]:
        raise FormatError(f"{path}: channel {name!r} stored as {a.dtype}, expected {FRAME_CHANNELS[name]}")
    return a


def _derived(name: str, depth: np.ndarray, rig_json: str, path: Path) -> np.ndarray:
    """Derived channel `name` of a format 2.x file (DERIVATIONS) from its depth and its header's rig."""
    if depth.dtype != np.float32:
        raise FormatError(f"{path}: channel 'depth' stored as {depth.dtype}, expected float32")
    try:
        rig = Rig.from_dict(json.loads(rig_json))
    except (ValueError, TypeError) as e:
        raise FormatError(f"{path}: header attribute {RIG_ATTRIBUTE!r} is not a rig ({e})") from None
    try:
        return DERIVATIONS[name](depth, rig)
    except ValueError as error:
        raise FormatError(f"{path}: channel {name!r}: {error}") from None
