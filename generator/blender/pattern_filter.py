"""Texture-space anti-aliasing of the projector pattern, and a 16-bit PNG writer (numpy + zlib).

Why: at one sample per pixel Cycles point-samples the pattern at one random spot in each camera
pixel, while a sensor pixel integrates over its area; dots smaller than a pixel then turn into
noise. Camera and projector sit a few centimetres apart, so a camera pixel covers almost exactly
fx_projector / fx_camera pattern pixels on any surface (the ratio of the focal lengths; depth
cancels out). Averaging the pattern over that footprint beforehand (as mip-mapping does for
textures) makes one sample worth a pixel's integral. Measured at 640 x 472, 300 objects, 1 sample:
correlation with a 128-sample render of the unfiltered pattern rose from 0.948 to 0.983.
The best width is a little under the footprint and depends on where the camera pixel grid falls
on the texel grid (see FOOTPRINT_FRACTION).
"""

from __future__ import annotations

import math
import struct
import zlib

import numpy as np

# Lines filtered at once: every line is filtered on its own, so a block of them at a time gives the
# same bits as the whole image while the temporaries stay a few MB (the full-size projector pattern
# is 3072 x 3072: 72 MB per float64 copy, and a render worker's memory peaked here).
BLOCK_LINES = 256


def _integral(cumulative: np.ndarray, lines: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Integral of each line from 0 to t (pixel k spans [k, k+1]); cumulative: the lines' cumulative
    sums along axis 0, a row of zeros first."""
    n = lines.shape[0]
    t = np.clip(t, 0, n)
    k = np.minimum(np.floor(t).astype(np.intp), n - 1)
    return cumulative[k] + (t - k)[:, None] * lines[k]


def _box_along(image: np.ndarray, width: float, axis: int) -> np.ndarray:
    """Mean of `image` (H, W) over a window `width` pixels wide centred on each pixel, along `axis`;
    the window may be fractional (partial pixels weigh by their covered length); the image is taken
    as zero outside its bounds, as the projector's CLIP texture is."""
    moved = np.moveaxis(np.asarray(image, np.float64), axis, 0)
    centres = np.arange(moved.shape[0]) + 0.5
    out = np.empty(moved.shape)
    for start in range(0, moved.shape[1], BLOCK_LINES):
        lines = moved[:, start:start + BLOCK_LINES]
        cumulative = np.concatenate([np.zeros((1, lines.shape[1])), np.cumsum(lines, axis=0)])
        out[:, start:start + BLOCK_LINES] = (_integral(cumulative, lines, centres + width / 2)
                                             - _integral(cumulative, lines, centres - width / 2)) / width
    return np.moveaxis(out, 0, axis)


def box_prefilter(image: np.ndarray, width: float) -> np.ndarray:
    """The image (H, W) averaged over a width x width pixel box around every pixel (float64).
    A width of at most 1 pixel is the identity."""
    if not (math.isfinite(width) and width > 0):
        raise ValueError(f"prefilter width must be a positive number of pixels, got {width!r}")
    if width <= 1.0:
        return np.asarray(image, np.float64)
    return _box_along(_box_along(image, width, 0), width, 1)


# Fraction of a camera pixel's footprint that the box prefilter spans. The rig fixes the sub-texel
# phase between camera pixel rows and pattern texel rows (the baseline is horizontal, so it is the
# same on every surface): full-size Structure Core (projector fx exactly 2 x camera fx, principal
# points at the image centres) puts every camera row boundary on a texel boundary; the 640 x 472
# scaling (1617 px projector) puts it mid-texel. Measured quality (bench.render_speed, 300 objects,
# 1 sample, two lights / none), fraction 0.75 / 0.85 / 1.0:
#   1216 x 896  0.982 / 0.981 / 0.977  and  0.983 / 0.982 / 0.978
#   640 x 472   0.979 / 0.9815 / 0.981  and 0.981 / 0.982 / 0.9825
# and 640 x 472 with the projector's cy moved by half a texel (aligned like full size): 0.982 at
# 0.75, 0.977 at 1.0, so the phase, not the resolution, decides. 0.85 is >= 0.98 at both phases.
FOOTPRINT_FRACTION = 0.85


def footprint_width(projector_fx: float, camera_fx: float, samples: int) -> float:
    """Prefilter width in pattern pixels: FOOTPRINT_FRACTION of one camera pixel's footprint
    (fx_p / fx_c), shrunk by sqrt(samples) because more samples average the pixel themselves
    (from 3 samples on, for a projector with twice the camera's focal length, the filter is off)."""
    return FOOTPRINT_FRACTION * projector_fx / camera_fx / math.sqrt(samples)


def png16_bytes(image: np.ndarray) -> bytes:
    """A 16-bit greyscale PNG (row 0 = top) of `image` (H, W) with values in [0, 1]."""
    height, width = image.shape
    levels = np.ascontiguousarray(np.round(np.clip(image, 0.0, 1.0) * 65535), dtype=">u2")
    rows = np.concatenate(
        [np.zeros((height, 1), np.uint8), levels.view(np.uint8).reshape(height, 2 * width)], 1
    )

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    header = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)  # 16-bit grey, no interlace
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", header)
        + chunk(b"IDAT", zlib.compress(rows.tobytes(), 1))
        + chunk(b"IEND", b"")
    )
