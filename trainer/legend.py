"""Legends under the trainer's colour-mapped images: a turbo colour bar with its units and range, and
a swatch for each special colour (black = outlier or no estimate, grey = no ground truth).

A reader of errors/*.png (dotsim eval) or NAME.png (dotsim infer) sees what every colour means
without the docs. numpy + OpenCV only.
"""

from __future__ import annotations

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
TEXT_SCALE = 0.4
TEXT_COLOUR = (235, 235, 235)
BACKGROUND = (40, 40, 40)
ROW = 18  # height of one legend row, px
BAR_WIDTH = 160
SWATCH = 12


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def legend_strip(width: int, low: float, high: float, unit: str,
                 swatches: tuple[tuple[tuple[int, int, int], str], ...] = ()) -> np.ndarray:
    """A BGR strip `width` px wide: 'low [bar] high unit' on the first row (turbo, as
    dotsim.show.colourise), then one row per (BGR colour, meaning) swatch."""
    rows = 1 + len(swatches)
    strip = np.full((rows * ROW + 4, width, 3), BACKGROUND, np.uint8)
    x = 4
    label = _fmt(low)
    cv2.putText(strip, label, (x, ROW - 5), FONT, TEXT_SCALE, TEXT_COLOUR, 1, cv2.LINE_AA)
    x += cv2.getTextSize(label, FONT, TEXT_SCALE, 1)[0][0] + 4
    bar_width = max(16, min(BAR_WIDTH, width - x - 120))
    ramp = np.linspace(0, 255, bar_width).astype(np.uint8)[None]
    bar = cv2.applyColorMap(np.repeat(ramp, ROW - 6, axis=0), cv2.COLORMAP_TURBO)
    if x + bar_width <= width:
        strip[3 : ROW - 3, x : x + bar_width] = bar
    x += bar_width + 4
    cv2.putText(strip, f"{_fmt(high)} {unit}", (x, ROW - 5), FONT, TEXT_SCALE, TEXT_COLOUR, 1, cv2.LINE_AA)
    for k, (colour, meaning) in enumerate(swatches, start=1):
        y = k * ROW
        cv2.rectangle(strip, (4, y + 3), (4 + SWATCH, y + 3 + SWATCH), colour, -1)
        cv2.rectangle(strip, (4, y + 3), (4 + SWATCH, y + 3 + SWATCH), TEXT_COLOUR, 1)
        cv2.putText(strip, meaning, (8 + SWATCH, y + ROW - 5), FONT, TEXT_SCALE, TEXT_COLOUR, 1,
                    cv2.LINE_AA)
    return strip


def with_legend(image: np.ndarray, low: float, high: float, unit: str,
                swatches: tuple[tuple[tuple[int, int, int], str], ...] = ()) -> np.ndarray:
    """image (H, W, 3) BGR with legend_strip(...) stacked under it."""
    return np.concatenate([image, legend_strip(image.shape[1], low, high, unit, swatches)], axis=0)
