"""How real a rendering looks beside a recording of the sensor it simulates (`dotsim capture compare`).

Both are measured the same way (capture.sensor_fit.measure: noise against level, dots; a rendering
compared with a one-frame recording each of its frames alone, as one-frame recordings are), plus two
numbers of one frame that need no projector-off frame, averaged over the scenes (scenes_look):

- the ambient light over the projector's: the background (a median over twice the recording's mean
  dot spacing) over the light above it, where the projector reaches (frame_ambient_ratio). It needs
  dots denser than the scene's own texture and edges: where they are sparse, the scene's structure
  counts as projector light and the ratio comes out low (projector-off frames, fit-sensor's
  on/off ratio, have no such limit);
- the share of pixels OpenCV's SGBM leaves without a disparity (unmatched_share): between the left and
  the right IR of a stereo pair, or between the IR frame and the reference pattern (the pattern as
  seen from infinity, dotsim.rig.geometry.reference_image, or a pattern image already in camera pixels) for a
  mono sensor, with GigaDepth's local contrast normalisation first (trainer.sgbm); the leftmost
  numDisparities columns, whose match may lie outside the reference, are not counted.

The rendering's sizes are converted to the recording's pixels by the ratio of their image widths (the
same camera at another [rig] scale; capture.static_recording.comparison_notes checks that). The table
(rows) holds each statistic for both and their ratio, rendering over recording; the picture
(draw) crops of both frames at the same scale side by side above fit-sensor's panels.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from scipy import ndimage

from capture.dots import DEFAULT_DOT_WINDOW
from capture.fit_report import draw_report
from capture.frames import CaptureError
from capture.sensor_fit import SensorStatistics
from dotsim import dataset
from dotsim.dataset import PATTERN_FILE
from dotsim.patterns import PatternError, load_pattern
from dotsim.rig.geometry import Rig, reference_image

# Lit: where the dots' light, averaged over the window, exceeds this share of its 99th percentile
# (as the visibility mask's threshold, capture.dots.DEFAULT_VISIBILITY_THRESHOLD).
LIT_SHARE = 0.05
# The crops of the picture: this share of the field of view around the image centre, drawn this wide.
CROP_SHARE = 0.3
CROP_WIDTH = 420


@dataclass(frozen=True)
class FrameLook:
    """One frame's looks: the mean projector-on frame (H, W), its ambient-to-projector ratio and the
    share of pixels SGBM leaves unmatched (None without a right frame or a reference pattern), and
    against what ("the right IR" or "the reference pattern")."""
    frame: np.ndarray
    ambient_ratio: float
    unmatched: float | None
    matched_against: str | None


def frame_ambient_ratio(frame: np.ndarray, window: int = DEFAULT_DOT_WINDOW) -> float:
    """Ambient light over projector light from one frame: the background (the median over `window` x
    `window` px, wide enough that dots are a minority of its pixels: a few dot spacings) over the light
    above it (signed, so the noise averages out instead of adding its positive half), both averaged
    where the projector reaches: where that light, averaged over the window, is more than LIT_SHARE of
    its 99th percentile (the gaps between the dots count as reached, as in a recording's on - off).

    >>> y, x = np.mgrid[0:60, 0:60]
    >>> dots = ((x % 6 == 3) & (y % 6 == 3)) * 0.6   # one dot in 36 px, 0.6 above the ambient
    >>> round(frame_ambient_ratio(0.2 + dots), 2)     # 0.2 / (0.6 / 36)
    12.0
    """
    frame = np.asarray(frame, np.float64)
    background = ndimage.median_filter(frame, size=window, mode="nearest")
    light = frame - background
    spread = ndimage.uniform_filter(light, window, mode="nearest")
    lit = spread > LIT_SHARE * np.percentile(spread, 99)
    return float(background[lit].mean() / max(light[lit].mean(), 1e-12))


def _disparity(left: np.ndarray, right: np.ndarray, num_disparities: int, stereo: bool) -> np.ndarray:
    """SGBM's disparity (nan: none) between a stereo pair's left and right IR (stereo) or an IR frame
    and its reference pattern (with LCN), right of the first num_disparities columns, whose match may
    lie outside the other image."""
    from trainer.sgbm import sgbm_disparity, stereo_sgbm_disparity

    if stereo:
        disparity = stereo_sgbm_disparity(left, right, num_disparities)
    else:
        disparity = sgbm_disparity(left, right, num_disparities, preprocessing="lcn")
    return disparity[:, num_disparities:]


def unmatched_share(left: np.ndarray, right: np.ndarray, num_disparities: int, stereo: bool) -> float:
    """The share of pixels, right of the first num_disparities columns, SGBM gives no disparity:
    between a stereo pair's left and right IR (stereo) or an IR frame and its reference pattern."""
    return float(np.mean(~np.isfinite(_disparity(left, right, num_disparities, stereo))))


def matched_depths(frame: np.ndarray, reference: np.ndarray, fx: float, baseline: float,
                   num_disparities: int) -> np.ndarray:
    """The depths (m) of the pixels SGBM (LCN) matches between a mono frame and its reference pattern,
    z = fx b / d, right of the first num_disparities columns (as unmatched_share counts): where a
    recording's surfaces lie, to render scenes at the same depths beside it.

    >>> rng = np.random.default_rng(0)
    >>> pattern = (rng.random((80, 200)) < 0.1).astype(float)
    >>> frame = np.roll(pattern, 20, axis=1)   # a wall at fx b / 20
    >>> depths = matched_depths(frame, pattern, 580.0, 0.075, 32)
    >>> round(float(np.median(depths)), 3), 580.0 * 0.075 / 20
    (2.175, 2.175)
    """
    disparity = _disparity(frame, reference, num_disparities, stereo=False)
    matched = disparity[np.isfinite(disparity) & (disparity > 0)]
    return fx * baseline / matched


def frame_look(frame: np.ndarray, num_disparities: int, reference: np.ndarray | None = None,
               right: np.ndarray | None = None, window: int = DEFAULT_DOT_WINDOW) -> FrameLook:
    """The looks of a mean projector-on frame: matched against the right IR when there is one, else
    against the reference pattern when there is one (camera pixels, the frame's size)."""
    against = other = None
    if right is not None:
        against, other = "left-right IR", right
    elif reference is not None:
        against, other = "against the reference pattern", reference
    for name, image in (("right IR", right), ("reference pattern", reference)):
        if image is not None and image.shape != frame.shape:
            raise CaptureError(f"the {name} is {image.shape[1]} x {image.shape[0]} px, the frame "
                               f"{frame.shape[1]} x {frame.shape[0]} px")
    unmatched = None if other is None else unmatched_share(frame, other, num_disparities, right is not None)
    return FrameLook(frame, frame_ambient_ratio(frame, window), unmatched, against)


def dot_reach(stats: SensorStatistics) -> int:
    """Twice the mean spacing of the dots fit-sensor found (px, odd, at least the dot window): the
    window of frame_ambient_ratio."""
    width, height = stats.recording.size
    spacing = np.sqrt(width * height * len(stats.recording.frame_counts) / max(stats.dots_detected, 1))
    return max(DEFAULT_DOT_WINDOW, 2 * int(round(spacing)) + 1)


def dataset_frames(root: Path, one_frame: bool = False) -> tuple[
        list[np.ndarray], np.ndarray | None, list[np.ndarray] | None, Rig, float | None]:
    """A dataset's scenes: (each scene's mean ir frame, or its first frame alone with `one_frame` (the
    noise of one frame, as a one-frame recording has), its pattern as seen from infinity in camera pixels
    or None without DATASET/pattern.png, each scene's mean (or first) ir_right or None, its rig (the
    first scene's), the nearest distance of the config it was rendered with ([scene] distance's lower
    bound; None for a recording))."""
    data = dataset.open_dataset(root)
    frames, rights, meta = [], [], None
    for ref in data.scenes:
        scene_meta = dataset.read_scene_meta(ref.path)
        meta = meta or scene_meta
        channels = [name for name in ("ir", "ir_right") if name in scene_meta["channels"]]
        # the frames used only (the first alone with one_frame), each scene.json read once
        used = [dataset.read_frame(ref.path / entry["file"], channels=channels, meta=scene_meta)
                for entry in scene_meta["frames"][:1 if one_frame else None]]
        frames.append(np.mean([f["ir"].astype(np.float64) for f in used], axis=0))
        if "ir_right" in channels:
            rights.append(np.mean([f["ir_right"].astype(np.float64) for f in used], axis=0))
    rig = Rig.from_dict(meta["rig"], f"{data.scenes[0].path} rig")
    reference = None
    if (root / PATTERN_FILE).is_file():
        try:
            pattern = load_pattern(root / PATTERN_FILE, (rig.projector.height, rig.projector.width)).image
        except PatternError as error:
            raise CaptureError(str(error)) from None
        reference = reference_image(pattern, rig, supersample=4).astype(np.float64)
    distance = meta.get("config", {}).get("scene", {}).get("distance")
    return frames, reference, rights or None, rig, float(distance[0]) if distance else None


def scenes_look(frames: list[np.ndarray], num_disparities: int, reference: np.ndarray | None = None,
                rights: list[np.ndarray] | None = None, window: int = DEFAULT_DOT_WINDOW) -> FrameLook:
    """The looks of several scenes' frames (frame_look of each): the means of their ambient-to-projector
    ratios and unmatched shares, and the first scene's frame (for the picture)."""
    looks = [frame_look(frame, num_disparities, reference, None if rights is None else rights[k], window)
             for k, frame in enumerate(frames)]
    unmatched = None if looks[0].unmatched is None else float(np.mean([look.unmatched for look in looks]))
    return FrameLook(looks[0].frame, float(np.mean([look.ambient_ratio for look in looks])), unmatched,
                     looks[0].matched_against)


def rows(real: SensorStatistics, real_look: FrameLook, rendered: SensorStatistics,
         rendered_look: FrameLook) -> list[tuple[str, float | None, float | None]]:
    """(statistic, the recording's value, the rendering's) in the recording's pixels."""
    ratio = real.recording.size[0] / rendered.recording.size[0]  # recording px per rendering px
    against = real_look.matched_against or rendered_look.matched_against or "no reference"
    level = float(np.median(real_look.frame))

    def per_area(stats: SensorStatistics, scale: float) -> float:
        width, height = stats.recording.size
        return 1000 * stats.dots_detected / (width * height * len(stats.recording.frame_counts)) / scale**2

    return [
        (f"noise at the recording's median level {level:.3g}", float(real.noise.sigma(level)),
         float(rendered.noise.sigma(level))),
        ("read noise", real.read_noise.value, rendered.read_noise.value),
        ("shot noise at full scale", real.shot_noise.value, rendered.shot_noise.value),
        ("dot FWHM, recording px", real.dot_fwhm.value, rendered.dot_fwhm.value * ratio),
        ("dot peak SNR, one frame (median)", float(np.median(real.snr)), float(np.median(rendered.snr))),
        ("dots per 1000 recording px", per_area(real, 1.0), per_area(rendered, ratio)),
        ("ambient / projector light, one frame", real_look.ambient_ratio, rendered_look.ambient_ratio),
        (f"SGBM unmatched share ({against})", real_look.unmatched, rendered_look.unmatched),
    ]


def table_text(table: list[tuple[str, float | None, float | None]]) -> str:
    """The rows as a text table with the ratio rendering / recording."""
    width = max(len(name) for name, _, _ in table) + 2
    lines = [f"{'statistic':{width}}{'recording':>12}{'rendering':>12}{'ratio':>9}"]
    for name, real, rendered in table:
        def cell(value):
            return f"{'-':>12}" if value is None else f"{value:>12.4g}"
        ratio = "-" if real is None or rendered is None or real == 0 else f"{rendered / real:.3g}"
        lines.append(f"{name:{width}}{cell(real)}{cell(rendered)}{ratio:>9}")
    return "\n".join(lines)


def _crop(frame: np.ndarray, share: float, width: int) -> np.ndarray:
    """The central `share` of the frame's field of view, scaled to `width` px (nearest: pixels stay
    visible), grey 0..255 by its own 99.5th percentile, as BGR."""
    height, full = frame.shape
    w, h = max(2, round(full * share)), max(2, round(height * share))
    x0, y0 = (full - w) // 2, (height - h) // 2
    crop = frame[y0:y0 + h, x0:x0 + w]
    grey = np.clip(crop / max(float(np.percentile(crop, 99.5)), 1e-12) * 255, 0, 255).astype(np.uint8)
    grey = cv2.resize(grey, (width, round(width * h / w)), interpolation=cv2.INTER_NEAREST)
    return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR)


def draw(real: SensorStatistics, real_look: FrameLook, rendered: SensorStatistics,
         rendered_look: FrameLook) -> np.ndarray:
    """The picture: the central CROP_SHARE of both frames' fields of view side by side (so at the same
    scale), the recording left, above fit-sensor's panels (noise against level, FWHM and SNR
    histograms, dots per area by depth), as a BGR image."""
    panels = draw_report(real, rendered)
    crops = [_crop(look.frame, CROP_SHARE, CROP_WIDTH) for look in (real_look, rendered_look)]
    height = max(c.shape[0] for c in crops) + 30
    strip = np.full((height, panels.shape[1], 3), panels[0, 0], np.uint8)
    for k, (crop, name) in enumerate(zip(crops, ("recording", "rendering"), strict=True)):
        x = 10 + k * (CROP_WIDTH + 20)
        strip[24:24 + crop.shape[0], x:x + crop.shape[1]] = crop
        cv2.putText(strip, f"{name}: central {100 * CROP_SHARE:g}% of the view", (x, 16),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.45, (235, 235, 235), 1, cv2.LINE_AA)
    return np.concatenate([strip, panels], axis=0)

