"""A stride-2 network's output brought to full resolution: its samples at pixels (2i, 2j) kept, the
pixels between them filled (trainer.checkpoint.predict_disparity; eval's half-resolution floor)."""

from __future__ import annotations

import numpy as np

from dotsim.lcn import lcn
from dotsim.rig.geometry import Rig, reference_image

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


# The pattern-guided choice (pattern_guided_disparity), chosen on the 24 validation frames of the
# corrected Table 2 data with the 60-minute benchmark's network (docs/results/trainer_scaling.md
# "Pixels between samples chosen by the pattern"), o(0.5): 0.98 % with the farther sample; one 9 x 9
# window 0.57 %; shiftable windows, the best of those centred up to 2 px away, 7 x 7: 0.51 % (kept;
# 5 x 5: 0.55, 9 x 9: 0.53; centres 0 or 1 px away 0.53, 0 or 3 px 0.56). LCN of 3, 5, 7, 9, 11 px
# gave 0.53, 0.55, 0.61, 0.68, 0.75 % (one window, an earlier candidate set): 5 is kept as the smallest
# that is not a pixel's own contrast (3 with shiftable windows: 0.51 as well). Choosing only where the
# samples differ by over 1.5, 2 or 3 px instead of 1: 0.56, 0.60, 0.62 %. Samples that differ by more
# than the 0.5 px the score allows cannot both be right about a pixel between them, so the pattern
# judges from 0.5 px (MATCH_JUMP_PX; the same page, "The pattern judges from 0.5 px"): 0.509 -> 0.480 %
# with that network, 0.528 -> 0.492 % with the second run's (0.2-0.6 px gave 0.479-0.482 and
# 0.486-0.495 %). With the GT's samples (eval's floor row) it costs 0.365 -> 0.414 %: it pays for
# samples that are unsure, as a network's are. 0.35 -> 0.58 s a frame.
MATCH_RADIUS = 3  # 7 x 7 windows
WINDOW_SHIFTS = (-2, -1, 0, 1, 2)  # px from the pixel, along each axis, of the windows' centres
MATCH_LCN_WINDOW = 5
MATCH_LCN_EPS = 0.003  # images in fractions of full scale, as trainer/sgbm.py's LCN
NEIGHBOUR_PX = 2  # a pixel's candidates: the samples within 2 px along each axis (2 or 3 per axis)
MATCH_JUMP_PX = 0.5  # the pattern judges where a pixel's candidate samples differ by more than this


def pattern_reference(pattern: np.ndarray, rig: Rig) -> np.ndarray:
    """The pattern (the projector image) as seen from infinity on the rig's camera grid, 4 x 4 rays a
    pixel (dotsim.rig.geometry.reference_image): what eval's SGBM and pattern_guided_disparity match
    the IR against."""
    return reference_image(pattern, rig, supersample=4)


def window_costs(ir_lcn: np.ndarray, reference_lcn: np.ndarray, ys: np.ndarray, xs: np.ndarray,
                 candidates: np.ndarray, radius: int = MATCH_RADIUS,
                 shifts: tuple[int, ...] = WINDOW_SHIFTS) -> np.ndarray:
    """(K, N) matching costs of pixels (ys[n], xs[n]) at candidate disparities candidates[k, n] (camera
    px): the sum of |IR - reference moved by d| on LCN'd images over a (2 radius + 1)^2 window, the
    smallest over the windows centred `shifts` px from the pixel along each axis (shiftable windows:
    near a depth edge one of them lies on the pixel's own surface). A surface at disparity d shows the
    reference's column u - d at column u (dotsim.rig.geometry.reference_image); the reference is read
    linearly between its columns. Pixels past the image's border are its edge pixels. inf where a
    candidate is nan.

    >>> ref = np.tile(np.sin(np.arange(40.0)), (13, 1)); seen = np.roll(ref, 3, axis=1)  # d = 3 px
    >>> at = np.array([6]), np.array([20])
    >>> costs = window_costs(seen, ref, *at, np.array([[3.0], [2.0], [np.nan]]), 2, shifts=(0,))
    >>> float(costs[0, 0]), float(costs[2, 0])
    (0.0, inf)
    >>> def by_hand(centre):  # 5 rows alike, columns centre - 2 .. centre + 2
    ...     return 5 * sum(abs(np.sin(u - 3) - np.sin(u - 2)) for u in range(centre - 2, centre + 3))
    >>> bool(np.isclose(costs[1, 0], by_hand(20)))
    True
    >>> shifted = window_costs(seen, ref, *at, np.array([[2.0]]), 2, shifts=(-2, 0, 2))
    >>> bool(np.isclose(shifted[0, 0], min(by_hand(18), by_hand(20), by_hand(22))))
    True
    """
    height, width = ir_lcn.shape
    reach = radius + max(abs(s) for s in shifts)
    padded = np.pad(ir_lcn, reach, mode="edge")
    offsets = range(-reach, reach + 1)
    costs = np.empty(candidates.shape)
    for k, disparity in enumerate(np.nan_to_num(candidates)):
        # |IR - reference| at every offset the windows reach, then each window's sum from running sums
        differences = np.empty((len(offsets), len(offsets), len(ys)))
        for i, dy in enumerate(offsets):
            rows = np.clip(ys + dy, 0, height - 1)
            for j, dx in enumerate(offsets):
                at = xs + dx - disparity
                left = np.floor(at)
                weight = at - left
                expected = (reference_lcn[rows, np.clip(left, 0, width - 1).astype(int)] * (1 - weight)
                            + reference_lcn[rows, np.clip(left + 1, 0, width - 1).astype(int)] * weight)
                differences[i, j] = np.abs(padded[ys + dy + reach, xs + dx + reach] - expected)
        total = np.pad(differences, ((1, 0), (1, 0), (0, 0))).cumsum(0).cumsum(1)
        costs[k] = np.inf
        for sy in shifts:
            top, bottom = reach + sy - radius, reach + sy + radius + 1
            for sx in shifts:
                first, last = reach + sx - radius, reach + sx + radius + 1
                window = total[bottom, last] - total[top, last] - total[bottom, first] + total[top, first]
                costs[k] = np.minimum(costs[k], window)
    return np.where(np.isnan(candidates), np.inf, costs)


def neighbour_samples(samples: np.ndarray, height: int, width: int) -> np.ndarray:
    """(9, height, width): for each full-resolution pixel the samples (at pixels (2i, 2j)) within
    NEIGHBOUR_PX px of it along each axis, nan in the slots past that or past the samples' edge."""
    def nearby(n: int, count: int) -> tuple[np.ndarray, np.ndarray]:
        at = np.arange(n)[None] // 2 + np.array([-1, 0, 1])[:, None]  # (3, n) sample indices
        usable = (abs(2 * at - np.arange(n)[None]) <= NEIGHBOUR_PX) & (at >= 0) & (at < count)
        return np.clip(at, 0, count - 1), usable

    (rows, row_ok), (cols, col_ok) = nearby(height, samples.shape[0]), nearby(width, samples.shape[1])
    out = samples[rows[:, None, :, None], cols[None, :, None, :]]  # (3, 3, height, width)
    usable = row_ok[:, None, :, None] & col_ok[None, :, None, :]
    return np.where(usable, out, np.nan).reshape(9, height, width)


def pattern_guided_disparity(samples: np.ndarray, ir: np.ndarray, reference: np.ndarray,
                             jump: float = MATCH_JUMP_PX) -> np.ndarray:
    """Disparity at every pixel of `ir` from a stride-2 network's samples at pixels (2i, 2j), with
    the pattern as the judge on depth edges. Where the samples near a pixel (neighbour_samples) agree
    within `jump`, the pixel is upsample_half's (linear between samples). Where they differ, the pixel
    (a sample's own pixel included: a network blurs across an edge) takes whichever of them, or of
    upsample_half's value (the farther sample), has its window (window_costs) best matched by the IR against
    `reference` (the pattern as seen from infinity on the camera grid): the surface its own dots say
    it lies on, not always the farther one."""
    height, width = ir.shape
    base = upsample_half(samples, height, width, jump=jump)
    near = neighbour_samples(np.asarray(samples, np.float64), height, width)
    ys, xs = np.nonzero(np.fmax.reduce(near, 0) - np.fmin.reduce(near, 0) > jump)
    candidates = np.concatenate([base[None, ys, xs], near[:, ys, xs]])
    costs = window_costs(lcn(np.asarray(ir, np.float64), MATCH_LCN_WINDOW, MATCH_LCN_EPS),
                         lcn(np.asarray(reference, np.float64), MATCH_LCN_WINDOW, MATCH_LCN_EPS),
                         ys, xs, candidates)
    out = base.copy()
    out[ys, xs] = candidates[np.argmin(costs, 0), np.arange(len(ys))]
    return out


def full_resolution_disparity(samples: np.ndarray, height: int, width: int, ir: np.ndarray | None = None,
                              reference: np.ndarray | None = None) -> np.ndarray:
    """Disparity known at full-resolution pixels (2i, 2j) (a stride-2 network's output) -> (height,
    width) as eval scores it and infer writes it: the samples kept, the pixels between them linear;
    across a depth jump the farther surface (upsample_half with DEPTH_JUMP_PX), or, given the frame's
    `ir` and the `reference` pattern, the surface the pixel's window matches (pattern_guided_disparity)."""
    if reference is not None:
        return pattern_guided_disparity(samples, ir, reference)
    return upsample_half(samples, height, width, jump=DEPTH_JUMP_PX)
