"""False colour that a reader can read without the docs: a value range as the turbo colour map, and
the legend strip stacked under such an image ('low [bar] high unit', then what special colours
mean). `dotsim show`'s sheets, `dotsim view`'s error images, `dotsim eval`'s error strips and `dotsim
infer`'s disparity images all draw with these, in one text style (the constants below). An image
narrower than a legend or a label needs is scaled up by a whole factor first (legible), so that the
text beside it is readable and never drawn over it. numpy + OpenCV only.

>>> import numpy as np
>>> image = colourise(np.array([[0.0, 5.0, np.nan]]), 0.0, 5.0)
>>> image.shape, image.dtype, image[0, 2].tolist()  # BGR; no value -> black
((1, 3, 3), dtype('uint8'), [0, 0, 0])
>>> legible(image).shape  # 3 px wide: each pixel a 160 x 160 block
(160, 480, 3)
>>> with_legend(image, 0.0, 5.0, "px").shape[:2] == (160 + LINE + 4, 480)
True
>>> labels = label_colours(np.array([[0, 1, 1, 7]]))[0]  # one colour per label, 0 black
>>> labels[0].tolist(), bool((labels[1] == labels[2]).all()), bool((labels[1] == labels[3]).all())
([0, 0, 0], True, False)
"""

from __future__ import annotations

import cv2
import numpy as np

FONT = cv2.FONT_HERSHEY_SIMPLEX
TEXT_SCALE = 0.45
LINE = 18  # text line height, px
LEGEND_BAR_WIDTH = 160  # the colour bar of legend_strip, px
SWATCH = 12  # a legend swatch's side, px
# The narrowest image a legend is stacked under (legible): a legend row at TEXT_SCALE needs about this.
LEGIBLE_WIDTH = 480
BACKGROUND = (40, 40, 40)
TEXT_COLOUR = (235, 235, 235)


def colourise(image: np.ndarray, low: float, high: float) -> np.ndarray:
    """Turbo colour map of image over [low, high] (BGR uint8); non-finite pixels black."""
    finite = np.isfinite(image)
    span = high - low if high > low else 1.0
    x = np.where(finite, (image.astype(np.float64) - low) / span, 0.0)
    bgr = cv2.applyColorMap(np.rint(np.clip(x, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    bgr[~finite] = 0
    return bgr


def label_colours(labels: np.ndarray) -> np.ndarray:
    """A colour of its own per integer label (BGR uint8): hues a golden-ratio step apart, so labels
    next to each other in number differ in colour; 0 black (no object, or the room)."""
    values, inverse = np.unique(np.asarray(labels, np.int64), return_inverse=True)
    hues = np.rint((values * 0.6180339887 % 1.0) * 179).astype(np.uint8)
    saturation = np.where(values % 2, 230, 170).astype(np.uint8)
    hsv = np.stack([hues, saturation, np.full_like(hues, 240)], axis=-1)[None]
    palette = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0]
    palette[values == 0] = 0
    return palette[inverse.reshape(np.shape(labels))]


def normal_colours(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Unit normals as colour (BGR uint8): red, green, blue = (x + 1) / 2, (y + 1) / 2, (z + 1) / 2;
    black where there is none (nan)."""
    rgb = np.stack([x, y, z], axis=-1).astype(np.float64)
    finite = np.isfinite(rgb).all(axis=-1)
    bgr = np.rint(np.clip((np.nan_to_num(rgb[..., ::-1]) + 1) / 2, 0, 1) * 255).astype(np.uint8)
    bgr[~finite] = 0
    return bgr


def colour_image(rgb: np.ndarray, white: float | None = None) -> np.ndarray:
    """A colour camera's linear (H, W, 3) radiance as an image to look at (BGR uint8): value / `white`
    (default: its 99th percentile over all channels, so a lamp seen directly does not darken the rest),
    clipped to 1, sRGB-encoded (IEC 61966-2-1) as a screen expects.

    >>> colour_image(np.array([[[0.0, 0.5, 1.0]]]), white=1.0)[0, 0].tolist()  # BGR
    [255, 188, 0]
    """
    rgb = np.nan_to_num(np.asarray(rgb, np.float64))
    white = float(np.percentile(rgb, 99)) if white is None else float(white)
    linear = np.clip(rgb / white, 0.0, 1.0) if white > 0 else np.zeros_like(rgb)
    encoded = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)
    return np.rint(encoded[..., ::-1] * 255).astype(np.uint8)


def put_text(img, text, x, y, colour=TEXT_COLOUR, scale=TEXT_SCALE, width: int | None = None):
    """Draw text at (x, y); with `width`, in a smaller font where it would be wider than that."""
    if width is not None:
        scale = min(scale, scale * width / max(cv2.getTextSize(text, FONT, scale, 1)[0][0], 1))
    cv2.putText(img, text, (int(x), int(y)), FONT, scale, colour, 1, cv2.LINE_AA)


def short_number(v: float) -> str:
    """A value as legends write it: four significant digits."""
    return f"{v:.4g}"


def legend_strip(width: int, low: float, high: float, unit: str,
                 swatches: tuple[tuple[tuple[int, int, int], str], ...] = ()) -> np.ndarray:
    """A BGR strip `width` px wide to stack under a colourise()d image, so that a reader sees what
    every colour means without the docs: 'low [bar] high unit' on the first row, then one row per
    (BGR colour, meaning) swatch (e.g. black = no estimate)."""
    strip = np.full(((1 + len(swatches)) * LINE + 4, width, 3), BACKGROUND, np.uint8)
    label = short_number(low)
    put_text(strip, label, 4, LINE - 5)
    x = 8 + cv2.getTextSize(label, FONT, TEXT_SCALE, 1)[0][0]
    bar_w = max(16, min(LEGEND_BAR_WIDTH, width - x - 120))
    if x + bar_w <= width:
        strip[3:LINE - 3, x:x + bar_w] = colourise(np.linspace(low, high, bar_w)[None].repeat(LINE - 6, 0),
                                                   low, high)
    put_text(strip, f"{short_number(high)} {unit}", x + bar_w + 4, LINE - 5, width=width - x - bar_w - 8)
    for k, (colour, meaning) in enumerate(swatches, start=1):
        y = k * LINE
        cv2.rectangle(strip, (4, y + 3), (4 + SWATCH, y + 3 + SWATCH), colour, -1)
        cv2.rectangle(strip, (4, y + 3), (4 + SWATCH, y + 3 + SWATCH), TEXT_COLOUR, 1)
        put_text(strip, meaning, 8 + SWATCH, y + LINE - 5, width=width - 12 - SWATCH)  # smaller where narrow
    return strip


def legible(image: np.ndarray, width: int = LEGIBLE_WIDTH) -> np.ndarray:
    """`image` scaled up by the smallest whole factor that makes it at least `width` px wide, by nearest
    neighbour (each pixel a square block: no value blended with its neighbours), or as it is when it is
    that wide already."""
    factor = -(-width // image.shape[1])
    if factor <= 1:
        return image
    return cv2.resize(image, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)


def titled(image: np.ndarray, text: str, width: int) -> np.ndarray:
    """`image` (BGR) made legible at `width` px, under a LINE-high bar holding `text` (never drawn
    over the image)."""
    image = legible(image, width)
    bar = np.full((LINE, image.shape[1], 3), BACKGROUND, np.uint8)
    put_text(bar, text, 4, LINE - 5, width=image.shape[1] - 8)
    return np.concatenate([bar, image], axis=0)


def with_legend(image: np.ndarray, low: float, high: float, unit: str,
                swatches: tuple[tuple[tuple[int, int, int], str], ...] = ()) -> np.ndarray:
    """image (H, W, 3) BGR, made legible, with legend_strip(...) stacked under it."""
    image = legible(image)
    return np.concatenate([image, legend_strip(image.shape[1], low, high, unit, swatches)], axis=0)
