"""Independent geometry the Cycles tests compare renders with: where rays enter a box (slab test), and a
mask's pixels away from its border, which anti-aliasing cannot touch."""

from __future__ import annotations

import cv2
import numpy as np


def box_entry_distance(origins: np.ndarray, directions: np.ndarray, lower, upper) -> np.ndarray:
    """Slab test: entry distance t (along `directions`) of rays into the axis-aligned box [lower, upper];
    inf on a miss."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (np.asarray(lower) - origins) / directions
        t2 = (np.asarray(upper) - origins) / directions
    near = np.nanmax(np.minimum(t1, t2), axis=-1)
    far = np.nanmin(np.maximum(t1, t2), axis=-1)
    return np.where((far >= near) & (far > 0), near, np.inf)


def mask_core(mask: np.ndarray, pixels: int = 1) -> np.ndarray:
    """The mask without its border (`pixels` wide)."""
    return cv2.erode(mask.astype(np.uint8), np.ones((2 * pixels + 1,) * 2, np.uint8)).astype(bool)
