"""trainer/metrics.py: each metric's doctest, and hand-made cases."""

from __future__ import annotations

import doctest

import numpy as np

from trainer import metrics
from trainer.metrics import outlier_counts


def test_doctests():
    result = doctest.testmod(metrics)
    assert result.attempted >= len([n for n in dir(metrics) if callable(getattr(metrics, n))
                                     and getattr(metrics, n).__module__ == metrics.__name__])
    assert result.failed == 0


def test_outlier_counts_hand_computed():
    gt = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    pred = np.array([[1.4, 2.6, 3.0], [np.nan, 10.0, 7.5]])
    valid = np.array([[True, True, True], [True, True, False]])
    # valid errors: 0.4, 0.6, 0.0, none (nan -> outlier), 5.0 ; the 1.5 at (1, 2) is not valid
    pixels, over = outlier_counts(pred, gt, valid, thresholds=(0.5, 1.0, 2.0, 5.0))
    assert pixels == 5
    assert over == [3, 2, 2, 1]  # > 0.5: 0.6, nan, 5 | > 1: nan, 5 | > 2: nan, 5 | > 5: nan only


