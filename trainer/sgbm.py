"""The baseline: OpenCV StereoSGBM between the IR image and the pattern as seen from infinity.

As GigaDepth (docs/TRAINER.md "Evaluation"): the IR image is the left image, the reference image
(dotsim.rig.reference_image) the right one, minDisparity 0, 128 disparities at 1216 px width, block 5,
P1 = 8 * 25, P2 = 32 * 25. Both images are padded by numDisparities columns on the left, or the leftmost
columns would get no estimate. Each image is scaled to 8 bit by its own 99.5th percentile (the IR and
the pattern have unrelated units).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from dotsim.rig import Rig


def num_disparities_for(rig: Rig, at_full_width: int = 128, full_width: int = 1216) -> int:
    """The published 128 disparities scaled with the image width, rounded up to a multiple of 16."""
    return max(16, 16 * math.ceil(at_full_width * rig.camera.width / full_width / 16))


def _to_uint8(image: np.ndarray) -> np.ndarray:
    image = np.nan_to_num(np.asarray(image, np.float64))
    scale = np.percentile(image, 99.5)
    return np.clip(image * (255.0 / max(scale, 1e-12)), 0, 255).astype(np.uint8)


def sgbm_disparity(ir: np.ndarray, reference: np.ndarray, num_disparities: int = 128, block: int = 5,
                   p1: int = 8 * 25, p2: int = 32 * 25) -> np.ndarray:
    """Disparity (H, W) float32 in camera px (d = fx b / z), nan where SGBM gives no estimate.

    ir: the camera image; reference: the pattern as seen from infinity on the same pixel grid.
    """
    if ir.shape != reference.shape:
        raise ValueError(f"IR {ir.shape} and reference {reference.shape} must have the same shape")
    if num_disparities % 16 or num_disparities <= 0:
        raise ValueError(f"num_disparities must be a positive multiple of 16, got {num_disparities}")
    pad = ((0, 0), (num_disparities, 0))
    left = np.pad(_to_uint8(ir), pad)
    right = np.pad(_to_uint8(reference), pad)
    matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=block,
                                    P1=p1, P2=p2)
    raw = matcher.compute(left, right)[:, num_disparities:].astype(np.float32) / 16.0  # fixed point x16
    return np.where(raw >= 0, raw, np.nan).astype(np.float32)
