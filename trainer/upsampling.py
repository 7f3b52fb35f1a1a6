"""A stride-2 network's output brought to full resolution: its samples at pixels (2i, 2j) kept, the
pixels between them filled (trainer.checkpoint.predict_disparity; eval's half-resolution floor)."""

from __future__ import annotations

import numpy as np

# Neighbouring half-resolution samples further apart than this (camera px of disparity) lie on two
# surfaces: the pixel between them takes the farther one instead of their mean, so no "flying pixels"
# float between a foreground object and its background. Measured with dotsim/configs/train_cpu.toml
# (then with the published backbone) after 41 min (docs/TRAINER.md): o(0.5) 0.395 (linear) -> 0.369
# (nearer sample) -> 0.354 (farther) on the test split, 0.473 -> 0.448 -> 0.435 on 20 unseen
# train-asset scenes; 0.5 and 2 px gave within 0.001.
DEPTH_JUMP_PX = 1.0


def upsample_half(half: np.ndarray, height: int, width: int, jump: float | None = None) -> np.ndarray:
    """(h, w) values at full-res pixels (2i, 2j) -> (height, width), the native samples kept exactly.

    In between: the mean of the two neighbouring samples (linear), or, with `jump`, the smaller of the
    two where they differ by more than `jump` or one is nan (for disparity: the farther surface). The
    odd last row/column (if any) is extrapolated linearly from the two samples before it (copied from
    the last one across a jump). Applied along rows, then columns."""
    def along(a: np.ndarray, n: int, axis: int) -> np.ndarray:
        a = np.moveaxis(a, axis, 0)
        out = np.empty((n, *a.shape[1:]), np.float64)
        out[0::2] = a[: (n + 1) // 2]
        left, right = a[:-1], a[1:]
        inner = (left + right) / 2
        if jump is not None:
            inner = np.where(np.abs(left - right) <= jump, inner, np.fmin(left, right))
        out[1::2][: len(inner)] = inner[: n // 2]
        if n % 2 == 0:  # the last (odd) index has no sample to its right
            last = a[n // 2 - 1]
            if len(a) > 1:
                before = a[n // 2 - 2]
                extrapolated = 1.5 * last - 0.5 * before
                last = extrapolated if jump is None else np.where(np.abs(last - before) <= jump,
                                                                  extrapolated, last)
            out[n - 1] = last
        return np.moveaxis(out, 0, axis)

    return along(along(np.asarray(half, np.float64), height, 0), width, 1)


def full_resolution_disparity(samples: np.ndarray, height: int, width: int) -> np.ndarray:
    """Disparity known at full-resolution pixels (2i, 2j) (a stride-2 network's output) -> (height,
    width) as eval scores it: the samples kept, the pixels between them linear, across a depth jump the
    farther surface (upsample_half with DEPTH_JUMP_PX)."""
    return upsample_half(samples, height, width, jump=DEPTH_JUMP_PX)
