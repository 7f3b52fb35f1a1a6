"""Minimal reader for the one EXR layout the renderer writes: single part, scanline, no compression,
32-bit float channels. numpy + stdlib only, because Blender's own Python has no OpenEXR package and
loading through bpy.data.images applies colour management and leaves datablocks behind."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

_MAGIC = 20000630
_FLOAT = 2  # EXR pixel type code for 32-bit float


def _read_header(data: bytes, path: Path) -> tuple[dict[str, tuple[str, bytes]], int]:
    """Header attributes {name: (type, raw bytes)} and the offset just past the header."""
    if len(data) < 8 or struct.unpack_from("<i", data, 0)[0] != _MAGIC:
        raise ValueError(f"{path} is not an OpenEXR file")
    version = struct.unpack_from("<i", data, 4)[0]
    if version & 0x1A00:  # tiled, deep or multi-part (0x400, long names, is fine)
        raise ValueError(f"{path}: only single-part scanline EXR is supported (version flags {version:#x})")
    attributes: dict[str, tuple[str, bytes]] = {}
    offset = 8
    while data[offset] != 0:
        name_end = data.index(b"\0", offset)
        type_end = data.index(b"\0", name_end + 1)
        name = data[offset:name_end].decode()
        kind = data[name_end + 1 : type_end].decode()
        size = struct.unpack_from("<i", data, type_end + 1)[0]
        start = type_end + 5
        attributes[name] = (kind, data[start : start + size])
        offset = start + size
    return attributes, offset + 1


def _channels(raw: bytes) -> list[tuple[str, int]]:
    """[(name, pixel type)] from a chlist attribute (names are sorted in the file)."""
    channels = []
    offset = 0
    while raw[offset] != 0:
        end = raw.index(b"\0", offset)
        pixel_type = struct.unpack_from("<i", raw, end + 1)[0]
        channels.append((raw[offset:end].decode(), pixel_type))
        offset = end + 1 + 16  # pixel type, pLinear + reserved, xSampling, ySampling
    return channels


# Bytes read first for the header and the line offsets (Blender's header is under 1 kB, a line's
# offset 8 bytes); the pixels are then read straight into the image, line by line, so a read holds
# the image alone, never the whole file besides it (two such files per pose made a render worker's
# memory peak).
_HEAD_BYTES = 1 << 16


def read_exr(path: str | Path) -> dict[str, np.ndarray]:
    """Channels of an uncompressed float32 scanline EXR as {name: (H, W) float32}, row 0 at the top."""
    path = Path(path)
    with open(path, "rb") as stream:
        head = stream.read(_HEAD_BYTES)
        try:
            attributes, offset = _read_header(head, path)
        except (IndexError, ValueError, struct.error):
            if len(head) < _HEAD_BYTES:  # the whole file was read: it is what is wrong
                raise
            head += stream.read()  # a header larger than any Blender writes
            attributes, offset = _read_header(head, path)
        if attributes["compression"][1][0] != 0:
            raise ValueError(f"{path}: compression must be NONE, got code {attributes['compression'][1][0]}")
        channels = _channels(attributes["channels"][1])
        if any(pixel_type != _FLOAT for _, pixel_type in channels):
            raise ValueError(f"{path}: every channel must be 32-bit float, got {channels}")
        x0, y0, x1, y1 = struct.unpack("<4i", attributes["dataWindow"][1])
        width, height = x1 - x0 + 1, y1 - y0 + 1
        head += stream.read(max(0, offset + 8 * height - len(head)))
        line_offsets = np.frombuffer(head, "<u8", count=height, offset=offset).tolist()
        # Each chunk: int32 y, int32 byte count, then one line of every channel in name order.
        image = np.empty((height, len(channels), width), "<f4")
        for line_offset in line_offsets:
            stream.seek(line_offset)
            start = stream.read(8)  # int32 y, int32 byte count
            y = struct.unpack_from("<i", start)[0] - y0 if len(start) == 8 else -1
            if not 0 <= y < height or stream.readinto(image[y]) != image[y].nbytes:
                raise ValueError(f"{path}: line at byte {line_offset} is truncated or outside the image")
    return {name: image[:, k, :] for k, (name, _) in enumerate(channels)}
