"""The projector's signal in a real projector-on / projector-off pair: where it reaches, and the dots.

A real sensor gives no flood pass (projector replaced by a lit rectangle), only frames with the dot
projector on and off. Their difference is bright on the dots and dark between them, so "where
does the projector reach" needs the dots spread over the gaps first (dot_envelope), and dot
detection needs a threshold that follows the local brightness (falloff, a bright zero-order dot)
rather than the image maximum (local_dot_image).
"""

from __future__ import annotations

import cv2
import numpy as np

from dotsim.masks import exposure_scale, visibility_mask

DEFAULT_DOT_WINDOW = 7
DEFAULT_VISIBILITY_THRESHOLD = 0.05


def _check_window(window: int) -> int:
    if int(window) != window or window < 1:
        raise ValueError(f"dot window must be a positive integer (pixels), got {window}")
    return int(window)


def projector_signal(on: np.ndarray, off: np.ndarray | None) -> np.ndarray:
    """What the projector adds: on - off clipped at 0 (float32); `on` alone when off is None."""
    on = np.asarray(on, np.float32)
    if off is None:
        return on
    return np.clip(on - np.asarray(off, np.float32), 0.0, None)


def dot_envelope(signal: np.ndarray, window: int = DEFAULT_DOT_WINDOW) -> np.ndarray:
    """The projector signal (projector_signal) spread from the dots over the gaps between them (H, W).

    A 1-px Gaussian blur first averages the sensor noise down (so the maxima below do not pick
    noise peaks); then a morphological closing with a window x window square: the maximum filter
    carries each dot's brightness over the gaps to its neighbours, the minimum filter after it
    pulls the lit region's border back to where the outermost dots are, so a projector shadow
    keeps its width. window should be at least the largest gap between neighbouring dots in
    the camera image (px); gaps wider than the window stay dark.
    """
    window = _check_window(window)
    smooth = cv2.GaussianBlur(np.asarray(signal, np.float32), (0, 0), sigmaX=1.0,
                              borderType=cv2.BORDER_REPLICATE)
    kernel = np.ones((window, window), np.uint8)
    return cv2.morphologyEx(smooth, cv2.MORPH_CLOSE, kernel, borderType=cv2.BORDER_REPLICATE)


def capture_visibility(on: np.ndarray, off: np.ndarray, window: int = DEFAULT_DOT_WINDOW,
                       threshold: float = DEFAULT_VISIBILITY_THRESHOLD) -> np.ndarray:
    """Pattern visibility mask (bool (H, W)) of a real on/off pair.

    The dot envelope stands in for the simulator's flood pass minus ambient, so
    dotsim.masks.visibility_mask applies unchanged: visible where envelope > threshold x the
    99th percentile of (ambient + envelope).
    """
    off = np.asarray(off, np.float32)
    envelope = dot_envelope(projector_signal(on, off), window)
    return visibility_mask(off, off + envelope, threshold=threshold, relative=True)


def local_dot_image(signal: np.ndarray, window: int = DEFAULT_DOT_WINDOW,
                    threshold: float = DEFAULT_VISIBILITY_THRESHOLD) -> np.ndarray:
    """The projector signal divided by its smoothed local dot brightness; 0 where no dots reach.

    Dots then peak near 1 everywhere, so one threshold relative to the maximum (what
    dotsim.patterns.detect_dots applies) finds dim corner dots as well as central ones. The
    divisor is the dot envelope blurred over 4 windows: smooth enough that it barely tilts a dot's
    profile (a sub-pixel bias of about sigma^2 x its log-gradient, a few hundredths of a pixel),
    local enough to follow the cos/r^2 falloff. Pixels whose envelope is below threshold x its
    99th percentile (projector shadows, outside the pattern) are set to 0 so their noise makes
    no dots.
    """
    signal = np.asarray(signal, np.float32)
    envelope = dot_envelope(signal, window)
    scale = exposure_scale(envelope)
    if scale <= 0:
        return np.zeros_like(signal)
    local = cv2.GaussianBlur(envelope, (0, 0), sigmaX=4.0 * window, borderType=cv2.BORDER_REPLICATE)
    reached = envelope > threshold * scale
    return np.where(reached, signal / np.maximum(local, threshold * scale), 0.0).astype(np.float32)
