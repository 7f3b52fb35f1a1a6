"""bench/device_depth_picture.py: its summary's doctest (the picture itself is drawn from a rendered
dataset, docs/DEVICE_DEPTH.md)."""

from __future__ import annotations

import doctest

from bench import device_depth_picture


def test_doctests():
    result = doctest.testmod(device_depth_picture)
    assert result.attempted >= 2 and result.failed == 0
