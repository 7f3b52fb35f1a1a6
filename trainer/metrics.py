"""Metrics of a disparity estimate against ground truth: small pure functions, one per metric.

Disparities are in camera pixels at full resolution; `valid` selects the pixels that are scored. A
pixel a method gives no estimate for (nan) counts as wrong at every threshold, so no method gains by
abstaining. trainer/scoring.py (eval and training's validation), bench/sgbm_clean.py and
bench/trainer_accuracy.py compute every figure they print with these.
"""

from __future__ import annotations

import numpy as np

THRESHOLDS = (0.5, 1.0, 2.0, 5.0)  # o(t), camera px: GigaDepth's


def valid_pixels(visibility: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """The scored pixels: the pattern is visible and the GT disparity finite and positive.

    >>> valid_pixels(np.array([1, 1, 0, 1]), np.array([2.0, np.nan, 3.0, 0.0]))
    array([ True, False, False, False])
    """
    gt = np.asarray(gt)
    with np.errstate(invalid="ignore"):
        return (np.asarray(visibility) > 0) & np.isfinite(gt) & (gt > 0)


def outliers(pred: np.ndarray, gt: np.ndarray, t: float) -> np.ndarray:
    """Where |pred - gt| > t, or pred is no estimate (nan): bool, the shape of pred.

    >>> outliers(np.array([1.0, 1.4, 2.0, np.nan]), np.array([1.0, 1.0, 1.0, 1.0]), 0.5)
    array([False, False,  True,  True])
    """
    err = np.abs(np.asarray(pred, np.float64) - gt)
    return ~(err <= t)


def outlier_counts(pred: np.ndarray, gt: np.ndarray, valid: np.ndarray,
                   thresholds=THRESHOLDS) -> tuple[int, list[int]]:
    """(valid pixels, [valid pixels that are outliers at t, for t in thresholds]).

    >>> outlier_counts(np.array([1.0, 1.4, 2.0, np.nan]), np.ones(4), np.array([1, 1, 1, 0], bool), (0.5, 2))
    (3, [1, 0])
    """
    valid = np.asarray(valid, bool)
    return int(valid.sum()), [int((outliers(pred, gt, t) & valid).sum()) for t in thresholds]


def joint_outliers(pred_a: np.ndarray, pred_b: np.ndarray, gt: np.ndarray, valid: np.ndarray,
                   t: float) -> tuple[int, int, int, int]:
    """Valid pixels two methods get wrong at t: (both, only a, only b, neither).

    >>> gt = np.zeros(6)
    >>> a = np.array([0.0, 1.0, 1.0, 0.0, np.nan, 9.0])
    >>> b = np.array([0.0, 1.0, 0.0, 1.0, 0.0, 9.0])
    >>> joint_outliers(a, b, gt, np.array([1, 1, 1, 1, 1, 0], bool), 0.5)
    (1, 2, 1, 1)
    """
    valid = np.asarray(valid, bool)
    wrong_a, wrong_b = outliers(pred_a, gt, t) & valid, outliers(pred_b, gt, t) & valid
    return (int((wrong_a & wrong_b).sum()), int((wrong_a & ~wrong_b).sum()), int((~wrong_a & wrong_b).sum()),
            int((valid & ~wrong_a & ~wrong_b).sum()))


def outside_range(pred: np.ndarray, low: float, high: float, valid: np.ndarray) -> int:
    """Valid pixels whose estimate lies outside [low, high] (a feasible disparity range); pixels
    without an estimate are not counted.

    >>> outside_range(np.array([0.5, 2.0, 9.0, np.nan, 12.0]), 1.0, 10.0, np.array([1, 1, 1, 1, 0], bool))
    1
    """
    pred = np.asarray(pred, np.float64)
    with np.errstate(invalid="ignore"):
        return int((np.asarray(valid, bool) & np.isfinite(pred) & ((pred < low) | (pred > high))).sum())


def outlier_rate(count: int, pixels: int) -> float:
    """o(t): the share of scored pixels that are outliers; nan when no pixel was scored.

    >>> outlier_rate(1, 4), outlier_rate(0, 0)
    (0.25, nan)
    """
    return count / pixels if pixels else float("nan")


def ratio(rate: float, baseline: float) -> float:
    """rate / baseline (the goal compares the network's o(0.5) with SGBM's); inf when the baseline is 0.

    >>> ratio(0.2, 0.4), ratio(0.1, 0.0)
    (0.5, inf)
    """
    return rate / baseline if baseline else float("inf")
