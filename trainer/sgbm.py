"""The baselines: OpenCV StereoSGBM between the IR image and the pattern as seen from infinity, and
between the left and right IR images of a stereo pair.

As GigaDepth (docs/TRAINER.md "Evaluation"): the IR image is the left image, the reference image
(dotsim.rig.geometry.reference_image) the right one, minDisparity 0, block 5, P1 = 8 * 25, P2 = 32 * 25. The
disparity range is not the published 128 scaled with the width (at 608 px that is 64, which reaches
0.55 m only and so never finds most near pixels) but whatever the nearest depth of the data needs:
d_max = fx b / z_near, rounded up to a multiple of 16 (num_disparities_for). Both images are padded by
numDisparities columns on the left, or the leftmost columns would get no estimate.

Two preprocessings (PREPROCESSINGS): "plain" scales each image to 8 bit by its own 99.5th percentile
(the IR and the pattern have unrelated units); "lcn" first applies GigaDepth's local contrast
normalisation (dotsim.lcn, 11 px window), which evens out the falloff of the dots' brightness with
distance and albedo, then maps +-its 99.5th absolute percentile to 0..255. Which is better depends on
the data: trainer.evaluate picks it on validation frames, never on the frames it reports.

A stereo pair (stereo_sgbm_disparity) is matched as GigaDepth matches the two IR cameras of its
captured Structure Core data: the left IR as the left image, the right IR as the right one, block 5,
P1 = 200, P2 = 800, no LCN; both images on one 8-bit scale (the pair shares an exposure), and the
range either GigaDepth's 128 disparities scaled to the image width (published_num_disparities) or
sized to the data's nearest depth with the pair's baseline B (num_disparities_for(rig, z, B)). The
result is the left-right disparity d = fx B / z of the stored `stereo_disparity`.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from dotsim.lcn import lcn
from dotsim.rig.geometry import Rig

PREPROCESSINGS = ("plain", "lcn")
LCN_WINDOW = 11  # GigaDepth's window
# eps of the LCN, in the images' units (IR and pattern both 0..1): about the sensor's read noise, so
# flat dark regions stay flat instead of having their noise blown up to full contrast.
LCN_EPS = 0.003
# GigaDepth's SGM between the two IR cameras of captured Structure Core frames: 128 disparities at the
# camera's full width.
PUBLISHED_DISPARITIES = 128
PUBLISHED_WIDTH = 1216


def max_disparity(rig: Rig, nearest_depth: float, baseline: float | None = None) -> float:
    """Largest disparity (camera px, d = fx b / z) of a surface at `nearest_depth` metres; b is the
    projector's baseline, or `baseline` (metres: a stereo pair's B)."""
    if not nearest_depth > 0:
        raise ValueError(f"nearest depth must be > 0 m, got {nearest_depth}")
    return rig.camera.fx * abs(rig.baseline if baseline is None else baseline) / nearest_depth


def num_disparities_for(rig: Rig, nearest_depth: float, baseline: float | None = None) -> int:
    """SGBM's numDisparities for data no nearer than `nearest_depth` m (baseline: as max_disparity):
    the smallest multiple of 16 above the largest disparity (SGBM searches 0 .. numDisparities - 1,
    and subpixel refinement needs the integer disparity on either side of the true one)."""
    return 16 * max(1, math.ceil((math.ceil(max_disparity(rig, nearest_depth, baseline)) + 2) / 16))


def published_num_disparities(width: int) -> int:
    """GigaDepth's 128 disparities scaled to an image `width` px wide: a multiple of 16, at least 16.

    >>> published_num_disparities(1216), published_num_disparities(608), published_num_disparities(1280)
    (128, 64, 144)
    """
    return 16 * max(1, math.ceil(PUBLISHED_DISPARITIES * width / PUBLISHED_WIDTH / 16))


def _to_uint8(image: np.ndarray, scale: float | None = None) -> np.ndarray:
    """0..255 of `image` / `scale` (default: its own 99.5th percentile)."""
    image = np.nan_to_num(np.asarray(image, np.float64))
    scale = np.percentile(image, 99.5) if scale is None else scale
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
    if preprocessing not in PREPROCESSINGS:
        raise ValueError(f"SGBM preprocessing must be one of {PREPROCESSINGS}, got {preprocessing!r}")
    if preprocessing == "lcn":
        return _match(_lcn_uint8(ir), _lcn_uint8(reference), 128, num_disparities, block, p1, p2)
    return _match(_to_uint8(ir), _to_uint8(reference), 0, num_disparities, block, p1, p2)


def stereo_sgbm_disparity(left: np.ndarray, right: np.ndarray, num_disparities: int, block: int = 5,
                          p1: int = 8 * 25, p2: int = 32 * 25) -> np.ndarray:
    """Left-right disparity (H, W) float32 of a stereo pair in camera px (d = fx B / z, the stored
    `stereo_disparity`), nan where SGBM gives no estimate: GigaDepth's captured-data baseline.

    left, right: the pair's IR images (`ir`, `ir_right`), one exposure, so both are scaled to 8 bit by
    one factor (the pair's 99.5th percentile); no LCN. num_disparities: a positive multiple of 16
    (published_num_disparities, or num_disparities_for with the pair's baseline).
    """
    if left.shape != right.shape:
        raise ValueError(f"left {left.shape} and right {right.shape} IR must have the same shape")
    scale = float(np.percentile(np.nan_to_num(np.stack([left, right]).astype(np.float64)), 99.5))
    return _match(_to_uint8(left, scale), _to_uint8(right, scale), 0, num_disparities, block, p1, p2)


def _match(left: np.ndarray, right: np.ndarray, blank: int, num_disparities: int, block: int, p1: int,
           p2: int) -> np.ndarray:
    """StereoSGBM (minDisparity 0) of two 8-bit images, both padded by num_disparities columns of
    `blank` (what an unlit region maps to) on the left so that the leftmost columns get an estimate
    too; disparity in px, nan where there is none."""
    if num_disparities % 16 or num_disparities <= 0:
        raise ValueError(f"num_disparities must be a positive multiple of 16, got {num_disparities}")
    pad = ((0, 0), (num_disparities, 0))
    left = np.pad(left, pad, constant_values=blank)
    right = np.pad(right, pad, constant_values=blank)
    matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=num_disparities, blockSize=block,
                                    P1=p1, P2=p2)
    raw = matcher.compute(left, right)[:, num_disparities:].astype(np.float32) / 16.0  # fixed point x16
    return np.where(raw >= 0, raw, np.nan).astype(np.float32)
