"""The baseline: OpenCV StereoSGBM between the IR image and the pattern as seen from infinity.

As GigaDepth (docs/TRAINER.md "Evaluation"): the IR image is the left image, the reference image
(dotsim.rig.reference_image) the right one, minDisparity 0, block 5, P1 = 8 * 25, P2 = 32 * 25. The
disparity range is not the published 128 scaled with the width (at 608 px that is 64, which reaches
0.55 m only and so never finds most near pixels) but whatever the nearest depth of the data needs:
d_max = fx b / z_near, rounded up to a multiple of 16 (num_disparities_for). Both images are padded by
numDisparities columns on the left, or the leftmost columns would get no estimate.

Two preprocessings (PREPROCESSINGS): "plain" scales each image to 8 bit by its own 99.5th percentile
(the IR and the pattern have unrelated units); "lcn" first applies GigaDepth's local contrast
normalisation (dotsim.lcn, 11 px window), which evens out the falloff of the dots' brightness with
distance and albedo, then maps +-its 99.5th absolute percentile to 0..255. Which is better depends on
the data: trainer.evaluate picks it on validation frames, never on the frames it reports.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from dotsim.lcn import lcn
from dotsim.rig import Rig

PREPROCESSINGS = ("plain", "lcn")
LCN_WINDOW = 11  # GigaDepth's window
# eps of the LCN, in the images' units (IR and pattern both 0..1): about the sensor's read noise, so
# flat dark regions stay flat instead of having their noise blown up to full contrast.
LCN_EPS = 0.003


def max_disparity(rig: Rig, nearest_depth: float) -> float:
    """Largest disparity (camera px, d = fx b / z) of a surface at `nearest_depth` metres."""
    if not nearest_depth > 0:
        raise ValueError(f"nearest depth must be > 0 m, got {nearest_depth}")
    return rig.camera.fx * abs(rig.baseline) / nearest_depth


def num_disparities_for(rig: Rig, nearest_depth: float) -> int:
    """SGBM's numDisparities for data no nearer than `nearest_depth` m: the smallest multiple of 16
    above the largest disparity (SGBM searches 0 .. numDisparities - 1, and subpixel refinement needs
    the integer disparity on either side of the true one)."""
    return 16 * max(1, math.ceil((math.ceil(max_disparity(rig, nearest_depth)) + 2) / 16))


def _to_uint8(image: np.ndarray) -> np.ndarray:
    image = np.nan_to_num(np.asarray(image, np.float64))
    scale = np.percentile(image, 99.5)
    return np.clip(image * (255.0 / max(scale, 1e-12)), 0, 255).astype(np.uint8)


def _lcn_uint8(image: np.ndarray) -> np.ndarray:
    normalised = lcn(np.nan_to_num(np.asarray(image, np.float64)), LCN_WINDOW, LCN_EPS)
    scale = max(float(np.percentile(np.abs(normalised), 99.5)), 1e-12)
    return np.clip(127.5 + normalised * (127.5 / scale), 0, 255).astype(np.uint8)


def sgbm_disparity(ir: np.ndarray, reference: np.ndarray, num_disparities: int, block: int = 5,
                   p1: int = 8 * 25, p2: int = 32 * 25, preprocessing: str = "plain") -> np.ndarray:
    """Disparity (H, W) float32 in camera px (d = fx b / z), nan where SGBM gives no estimate.

    ir: the camera image; reference: the pattern as seen from infinity on the same pixel grid;
    num_disparities: a positive multiple of 16 (num_disparities_for); preprocessing: plain or lcn.
    """
    if ir.shape != reference.shape:
        raise ValueError(f"IR {ir.shape} and reference {reference.shape} must have the same shape")
    if num_disparities % 16 or num_disparities <= 0:
        raise ValueError(f"num_disparities must be a positive multiple of 16, got {num_disparities}")
    if preprocessing not in PREPROCESSINGS:
        raise ValueError(f"SGBM preprocessing must be one of {PREPROCESSINGS}, got {preprocessing!r}")
    to_uint8, blank = (_lcn_uint8, 128) if preprocessing == "lcn" else (_to_uint8, 0)
    pad = ((0, 0), (num_disparities, 0))  # filled with what an unlit region maps to
    left = np.pad(to_uint8(ir), pad, constant_values=blank)
    right = np.pad(to_uint8(reference), pad, constant_values=blank)
    matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=block,
                                    P1=p1, P2=p2)
    raw = matcher.compute(left, right)[:, num_disparities:].astype(np.float32) / 16.0  # fixed point x16
    return np.where(raw >= 0, raw, np.nan).astype(np.float32)
