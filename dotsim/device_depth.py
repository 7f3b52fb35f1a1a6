"""The depth a depth camera's own chip reports, simulated from rendered IR images (docs/DEVICE_DEPTH.md).

Two engines, each OpenCV's matcher with the device's thresholds around it, then the device's output
format:
- stereo (RealSense D4xx, Structure Core's pair): the left IR image against the right one with
  StereoSGBM (semi-global aggregation of a Birchfield-Tomasi cost on x-Sobel-prefiltered images,
  which like the D4xx's census cost ignores a brightness offset), its left-right consistency check
  (disp12MaxDiff) and uniqueness ratio (the D4xx's second-peak threshold);
- structured light (Kinect v1, Structure Core mono): the IR image against the device's reference
  image, the pattern as the camera sees it on a plane at a reference distance (reference_image_at),
  with StereoBM (block matching on normalised-response prefiltered images, which evens out the
  brightness between the scene and the reference).
Both then: a texture threshold (too little contrast in the block: no depth), a subpixel refinement
(windowed Lucas-Kanade steps from the matcher's 1/16 px estimate), a score threshold (the block must
match after refinement), no depth within a block of the image's edges, the disparity rounded to the
device's subpixel step, depth z = fx b / d rounded to the device's depth unit, and no depth (0) where
the disparity search cannot reach: outside [shift, shift + N - 1] (the device's range), and the band
of columns whose whole search would leave the second image (stereo: the left band the right camera
does not see; structured light: also a right band for surfaces beyond the reference distance).

Pure functions over numpy arrays; OpenCV is imported where it is used, because the settings
(DeviceDepthConfig, the config's [device_depth] table) travel in the scene spec, which Blender's own
Python imports with numpy alone.

>>> depth = quantised_depth(np.array([[10.0, 0.01, np.nan]]), fx_baseline=55.25, step=1 / 32, unit=0.001)
>>> depth.tolist()  # 10 px: 5.525 m; 0.01 px rounds to disparity 0: no depth
[[5.525000095367432, 0.0, 0.0]]
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from dotsim.config_schema import Checked, ConfigError, setting
from dotsim.lcn import lcn

ENGINES = ("off", "stereo", "structured_light")
# The largest value of the 16-bit depth word a device reports (z16): depth beyond 65535 units is no depth.
Z16_MAX = 65535
# Lucas-Kanade steps of the subpixel refinement: from the matcher's 1/16 px estimate, the median error
# on a noise-free textured plane was 0.009 px after one step, 0.0055 px after three, no better after six.
REFINE_STEPS = 3
# LCN window and eps for the refinement's images (dotsim.lcn; images as fractions of full scale).
REFINE_LCN_WINDOW = 11
REFINE_LCN_EPS = 0.003


@dataclass(frozen=True)
class DeviceDepthConfig(Checked):
    """The depth engine of the simulated device: the config's [device_depth] table (docs/CONFIG.md,
    docs/DEVICE_DEPTH.md). Disparities and the block are full-resolution camera pixels, scaled by
    `[rig] scale` when rendered smaller."""
    engine: str = setting("off", "the device's depth engine: off (no device_depth channel), stereo (left "
                          "IR against right IR, StereoSGBM: RealSense D4xx, Structure Core's pair; needs "
                          "[rig] stereo = true) or structured_light (IR against the reference image, "
                          "StereoBM: Kinect v1, Structure Core mono)", choices=ENGINES)
    num_disparities: int = setting(128, "disparities searched, full-resolution px (rounded up to a multiple "
                                   "of 16 after scaling); with disparity_shift it sets the nearest depth "
                                   "fx b / (shift + N - 1) and the left band of no depth (D4xx: 128)",
                                   low=16, high=1024)
    disparity_shift: int = setting(0, "smallest disparity searched, full-resolution px (the D4xx's "
                                   "disparity shift): larger moves the range nearer and sets the farthest "
                                   "depth fx b / shift", low=0, high=1024)
    block_size: int = setting(7, "matching window, px (odd; not scaled)", low=5, high=31)
    second_peak_threshold: int = setting(10, "uniqueness: the best match's cost must beat the second "
                                         "best by this many percent (OpenCV uniquenessRatio; the D4xx's "
                                         "second-peak threshold)", low=0, high=100)
    left_right_threshold: int = setting(1, "left-right check: largest difference, px, between the left "
                                        "image's disparity and the right image's at the matched point "
                                        "(OpenCV disp12MaxDiff; the D4xx's LR check threshold); -1: no "
                                        "check (stereo only)", low=-1, high=64)
    texture_threshold: float = setting(0.0, "smallest mean |difference| between horizontal neighbours "
                                       "over the block, 8-bit levels of the IR image (the D4xx's texture "
                                       "threshold; 0: off)", low=0.0, high=255.0)
    score_threshold: float = setting(0.25, "largest residual of the block after the subpixel refinement, as "
                                     "a share of the two blocks' variances, about 1 - their normalised "
                                     "correlation (0: a perfect match, 1: unrelated blocks, 2: off; the "
                                     "D4xx's score threshold): drops blocks the other image does not "
                                     "repeat (noise, occlusion, foreshortening)", low=0.0, high=2.0,
                                     low_open=True)
    subpixel_step: float = setting(1 / 32, "disparity step the device reports, px (D4xx 1/32, Kinect v1 "
                                   "1/8)", low=0.0, high=1.0, low_open=True)
    depth_unit: float = setting(0.001, "depth unit of the device's 16-bit output, m (1 mm)", low=1e-6,
                                high=1.0)
    reference_distance: float = setting(2.0, "distance of the plane the reference image shows, m "
                                        "(structured_light only)", low=0.05, high=100.0)

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.block_size % 2 == 0:
            raise ConfigError(f"DeviceDepthConfig.block_size = {self.block_size}: even; allowed: an odd "
                              f"number of px, 5 to 31")

    @property
    def on(self) -> bool:
        """Whether frames carry the device's depth."""
        return self.engine != "off"


def search_range(settings: DeviceDepthConfig, pixel_scale: float = 1.0) -> tuple[int, int]:
    """(smallest disparity, number of disparities) searched at a render scale, camera px: the shift
    scaled and rounded, the count scaled and rounded up to a multiple of 16 (OpenCV's matchers need it).

    >>> search_range(DeviceDepthConfig(num_disparities=128, disparity_shift=10), 0.5)
    (5, 64)
    """
    shift = int(round(settings.disparity_shift * pixel_scale))
    count = 16 * max(1, math.ceil(settings.num_disparities * pixel_scale / 16 - 1e-9))
    return shift, count


def searchable_columns(width: int, low: int, count: int) -> np.ndarray:
    """Columns (bool, (width,)) whose whole search, disparities low .. low + count - 1, stays inside the
    second image, which shows column u's point at u - d: u >= low + count - 1 and u - low <= width - 1.

    >>> searchable_columns(8, 0, 3).astype(int)  # the left band: 2 columns
    array([0, 0, 1, 1, 1, 1, 1, 1])
    >>> searchable_columns(8, -2, 3).astype(int)  # disparities -2 .. 0: a right band of 2
    array([1, 1, 1, 1, 1, 1, 0, 0])
    """
    u = np.arange(width)
    return (u >= low + count - 1) & (u - low <= width - 1)


def device_levels(image: np.ndarray) -> np.ndarray:
    """An IR image (fraction of full scale) as the 8 bits the matcher sees: full scale is 255."""
    return np.clip(np.rint(np.nan_to_num(np.asarray(image, np.float64)) * 255), 0, 255).astype(np.uint8)


def textured(levels: np.ndarray, block: int, threshold: float) -> np.ndarray:
    """Where the block around a pixel has texture: the mean |difference| between horizontal neighbours
    over block x block of the 8-bit image is at least `threshold` levels (bool; all True at 0).

    >>> flat = np.full((9, 9), 100, np.uint8)
    >>> bool(textured(flat, 5, 1.0)[4, 4]), bool(textured(flat, 5, 0.0)[4, 4])
    (False, True)
    """
    import cv2

    if threshold <= 0:
        return np.ones(levels.shape, bool)
    difference = np.zeros(levels.shape, np.float32)
    difference[:, 1:] = np.abs(np.diff(levels.astype(np.float32), axis=1))
    return cv2.blur(difference, (block, block), borderType=cv2.BORDER_REFLECT) >= threshold


def quantised_depth(disparity: np.ndarray, fx_baseline: float, step: float, unit: float) -> np.ndarray:
    """Depth (float32, metres) as the device reports it: the disparity rounded to `step` px, z = fx b / d
    rounded to `unit` m; 0 (no depth) where the disparity is missing, rounds to <= 0 or the depth
    exceeds the 16-bit word (Z16_MAX units)."""
    disparity = np.asarray(disparity, np.float64)
    steps = np.rint(np.where(np.isfinite(disparity), disparity, 0.0) / step)
    with np.errstate(divide="ignore"):
        units = np.rint(fx_baseline / (steps * step) / unit)
    valid = (steps > 0) & (units <= Z16_MAX) & (units > 0)
    return np.where(valid, units * unit, 0.0).astype(np.float32)


def as_channel(depth: np.ndarray) -> np.ndarray:
    """The device's depth as the `device_depth` channel stores it: metres, NaN where it gave none (0).

    >>> as_channel(np.array([0.0, 1.5], np.float32)).tolist()
    [nan, 1.5]
    """
    depth = np.asarray(depth, np.float32)
    return np.where(depth > 0, depth, np.nan).astype(np.float32)


def spline_row_sample(coefficients: np.ndarray, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each row at columns x (H, W) of the cubic B-spline whose coefficients (H, W) are given
    (scipy.ndimage.spline_filter1d along the rows makes them from an image, and the spline then passes
    through the samples): its value and x derivative, edge coefficients repeated. Keys' cubic
    convolution, or OpenCV's remap (positions rounded to 1/32 px), left the refined disparity of a
    noise-free plane 0.02 px off at the median; this spline 0.006 px.

    >>> from scipy.ndimage import spline_filter1d
    >>> row = np.arange(32, dtype=np.float64)[None, :] ** 2
    >>> value, slope = spline_row_sample(spline_filter1d(row, 3, axis=1), np.array([[15.5]]))
    >>> round(float(value[0, 0]), 2), round(float(slope[0, 0]), 2)  # x^2 at 15.5: 240.25, slope 31
    (240.25, 31.0)
    """
    height, width = coefficients.shape
    base = np.floor(x)
    t = (x - base).astype(np.float32)
    base = base.astype(np.intp)
    rows = np.arange(height)[:, None]
    # The B-spline's weights of the coefficients at base - 1 .. base + 2, and their derivatives in t.
    t2, t3, s = t * t, t * t * t, 1 - t
    weights = (s * s * s / 6, 0.5 * t3 - t2 + 2 / 3, -0.5 * t3 + 0.5 * t2 + 0.5 * t + 1 / 6, t3 / 6)
    slopes = (-0.5 * s * s, 1.5 * t2 - 2 * t, -1.5 * t2 + t + 0.5, 0.5 * t2)
    value = np.zeros(x.shape, np.float32)
    slope = np.zeros(x.shape, np.float32)
    for k, (w, dw) in enumerate(zip(weights, slopes, strict=True)):
        sample = coefficients[rows, np.clip(base + (k - 1), 0, width - 1)]
        value += w * sample
        slope += dw * sample
    return value, slope


def refine_disparity(left: np.ndarray, right: np.ndarray, disparity: np.ndarray, block: int,
                     steps: int = REFINE_STEPS) -> tuple[np.ndarray, np.ndarray]:
    """Subpixel refinement of a disparity map (float32, nan where none): windowed Lucas-Kanade steps
    on two images that agree up to the shift, left(u) = right(u - d). Returns the refined disparity
    and each block's residual share: the squared difference left over between the left block and the
    right one moved by the refined disparities, over the sum of the two blocks' variances (0: a perfect
    match, 1: blocks that have nothing in common; about 1 - their normalised correlation).

    Each step linearises right(u - d) about the current disparities of the block's pixels and takes,
    for each pixel, the d that minimises the block's squared residual (weights g^2, g the slope of the
    right image there): d = (sum g^2 d_q - sum g r) / sum g^2 over the block. A pixel that moves more
    than 1 px from the matcher's estimate, or whose block has no slope, gets none (nan).
    """
    import cv2
    from scipy.ndimage import spline_filter1d

    height, width = left.shape
    start = np.asarray(disparity, np.float32)
    valid = np.isfinite(start).astype(np.float32)
    d = np.where(valid > 0, start, 0.0).astype(np.float32)
    coefficients = spline_filter1d(np.asarray(right, np.float32), 3, axis=1)
    left = np.asarray(left, np.float32)
    columns = np.arange(width, dtype=np.float32)[None, :]
    window = (block, block)
    for _ in range(steps):
        warped, g = spline_row_sample(coefficients, columns - d)
        residual = (left - warped) * valid
        g *= valid
        weight = cv2.boxFilter(g * g, -1, window, normalize=False)
        total = cv2.boxFilter(g * g * d - g * residual, -1, window, normalize=False)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = np.where((valid > 0) & (weight > 1e-12), total / weight, 0.0).astype(np.float32)
    warped, _ = spline_row_sample(coefficients, columns - d)
    signal = sum(cv2.boxFilter((image - cv2.boxFilter(image, -1, window)) ** 2 * valid, -1, window,
                               normalize=False) for image in (left, warped))
    left_over = cv2.boxFilter((left - warped) ** 2 * valid, -1, window, normalize=False)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(signal > 0, left_over / signal, np.inf).astype(np.float32)
        kept = (valid > 0) & (np.abs(d - start) <= 1.0) & (weight > 1e-12)
    return np.where(kept, d, np.nan).astype(np.float32), share


def _match(left: np.ndarray, right: np.ndarray, low: int, count: int, settings: DeviceDepthConfig,
           semi_global: bool) -> np.ndarray:
    """OpenCV's disparity (float32 px, nan where none) of two 8-bit images for disparities low ..
    low + count - 1: the right image shifted by `low` columns so the matcher searches 0 .. count - 1,
    both padded so every column of the image gets an answer (searchable_columns says which mean one)."""
    import cv2

    pad = count + abs(low) + settings.block_size
    left = np.pad(left, ((0, 0), (pad, pad)))
    right = np.roll(np.pad(right, ((0, 0), (pad, pad))), low, axis=1)
    block = settings.block_size
    if semi_global:
        matcher = cv2.StereoSGBM_create(minDisparity=0, numDisparities=count, blockSize=block,
                                        P1=8 * block * block, P2=32 * block * block,
                                        disp12MaxDiff=settings.left_right_threshold,
                                        uniquenessRatio=settings.second_peak_threshold)
    else:
        matcher = cv2.StereoBM_create(numDisparities=count, blockSize=block)
        matcher.setUniquenessRatio(settings.second_peak_threshold)
        matcher.setTextureThreshold(0)  # the engine's own texture threshold applies to both engines
    raw = matcher.compute(left, right)[:, pad:-pad]
    return np.where(raw >= 0, raw.astype(np.float32) / 16.0 + low, np.nan).astype(np.float32)


def engine_disparity(image: np.ndarray, second: np.ndarray, low: int, count: int,
                     settings: DeviceDepthConfig, semi_global: bool) -> np.ndarray:
    """The engine's disparity (float32 camera px, nan where none) of `image` against `second` (both
    fractions of full scale, image(u) = second(u - d)), searched over low .. low + count - 1: the
    matcher, the texture threshold, the subpixel refinement, and no disparity in the columns whose
    search leaves the second image nor where the block leaves the image."""
    levels = device_levels(image)
    found = _match(levels, device_levels(second), low, count, settings, semi_global)
    found[:, ~searchable_columns(image.shape[1], low, count)] = np.nan
    # No depth within a block of the image's edges (OpenCV's block matcher leaves half a block): on a
    # noise-free plane about a fifth of the estimates in the 4 outermost rows were > 0.03 px off.
    margin = settings.block_size
    found[:margin], found[-margin:], found[:, :margin], found[:, -margin:] = np.nan, np.nan, np.nan, np.nan
    found[~textured(levels, settings.block_size, settings.texture_threshold)] = np.nan
    normalised = [lcn(np.nan_to_num(np.asarray(a, np.float32)), REFINE_LCN_WINDOW, REFINE_LCN_EPS)
                  for a in (image, second)]
    refined, share = refine_disparity(*normalised, found, settings.block_size)
    with np.errstate(invalid="ignore"):
        kept = (refined >= low) & (refined <= low + count - 1) & (share <= settings.score_threshold)
    return np.where(kept, refined, np.nan).astype(np.float32)


def _check_pair(image: np.ndarray, second: np.ndarray, names: str) -> None:
    if np.shape(image) != np.shape(second) or np.ndim(image) != 2:
        raise ValueError(f"{names} must be (H, W) images of one shape, got {np.shape(image)} and "
                         f"{np.shape(second)}")


def stereo_depth(left: np.ndarray, right: np.ndarray, fx: float, baseline: float,
                 settings: DeviceDepthConfig, pixel_scale: float = 1.0) -> np.ndarray:
    """The stereo engine's depth (float32 m, 0 = no depth) of a rectified pair: left and right IR
    (fractions of full scale), the right camera `baseline` m to the left camera's right, focal length
    fx px; the rendered images at `pixel_scale` of the device's resolution."""
    _check_pair(left, right, "left and right IR")
    low, count = search_range(settings, pixel_scale)
    disparity = engine_disparity(left, right, low, count, settings, semi_global=True)
    return quantised_depth(disparity, fx * baseline, settings.subpixel_step, settings.depth_unit)


def structured_light_depth(ir: np.ndarray, reference: np.ndarray, fx: float, baseline: float,
                           settings: DeviceDepthConfig, pixel_scale: float = 1.0) -> np.ndarray:
    """The structured-light engine's depth (float32 m, 0 = no depth) of an IR image against the
    device's reference image (reference_image_at: the pattern on a plane at
    settings.reference_distance), the projector `baseline` m along the camera's x axis, focal length fx
    px. The device searches absolute disparities shift .. shift + N - 1 (d = fx b / z); against the
    reference a surface at z shows the reference's dots moved by d - fx b / z_ref, the disparity the
    matcher finds. No left-right check: the reference has no view of its own to check against."""
    _check_pair(ir, reference, "IR and reference")
    shift, count = search_range(settings, pixel_scale)
    fx_baseline = fx * abs(baseline)
    at_reference = fx_baseline / settings.reference_distance
    low = math.floor(shift - at_reference)
    # With the projector to the camera's left the dots move the other way: match the mirror images.
    flip = (lambda a: a[:, ::-1]) if baseline < 0 else (lambda a: a)
    relative = flip(engine_disparity(flip(ir), flip(reference), low, count, settings, semi_global=False))
    disparity = relative + at_reference
    with np.errstate(invalid="ignore"):
        disparity = np.where((disparity >= shift) & (disparity <= shift + count - 1), disparity, np.nan)
    return quantised_depth(disparity, fx_baseline, settings.subpixel_step, settings.depth_unit)


def reference_image_at(pattern: np.ndarray, rig, distance: float) -> np.ndarray:
    """The structured-light device's reference image: the pattern as the rig's camera sees it on a
    plane at `distance` m facing it, as the chip stores a capture of a flat wall (float32 (H, W), its
    99.5th percentile scaled to 1). dotsim.oracle's projection: 4 x 4 rays per pixel, cos / r^2 falloff.
    """
    from dotsim.oracle import expected_pattern_image

    plane = np.full((rig.camera.height, rig.camera.width), distance, np.float32)
    image = expected_pattern_image(plane, rig, pattern)
    return (image / max(float(np.percentile(image, 99.5)), 1e-12)).astype(np.float32)
