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




def test_joint_outliers_hand_made():
    """A 3 x 4 frame with two pixels without ground truth (they count nowhere); errors written by hand:
    network 0, 3, .2, none | 1, 0, 0, 0 | -, 20, .3, -; SGBM 0, 2, .1, 0 | 1, 0, 5, 0 | -, 0, .3, -."""
    gt = np.full((3, 4), 10.0)
    network = np.array([[10.0, 13.0, 10.2, np.nan],
                        [11.0, 10.0, 10.0, 10.0],
                        [10.0, 30.0, 10.3, 20.0]])
    sgbm = np.array([[10.0, 12.0, 10.1, 10.0],
                     [9.0, 10.0, 15.0, 10.0],
                     [np.nan, 10.0, 10.3, 20.0]])
    valid = np.ones((3, 4), bool)
    valid[2, 0] = valid[2, 3] = False
    # t = 0.5: both (0,1) (1,0); only the network (0,3) (2,1); only SGBM (1,2); neither the other 5
    assert metrics.joint_outliers(network, sgbm, gt, valid, 0.5) == (2, 2, 1, 5)
    # t = 1: an error of exactly 1 is no outlier, so (1,0) is right for both
    assert metrics.joint_outliers(network, sgbm, gt, valid, 1.0) == (1, 2, 1, 6)
    # t = 5: only the network's missing estimate and its 20 px error
    assert metrics.joint_outliers(network, sgbm, gt, valid, 5.0) == (0, 2, 0, 8)


def test_outside_range_counts_finite_estimates_beyond_either_end():
    pred = np.array([0.1, 0.35, 7.0, 7.1, np.nan, 100.0])
    assert metrics.outside_range(pred, 0.35, 7.06, np.array([1, 1, 1, 1, 1, 0], bool)) == 2
