"""What `dotsim capture fit-sensor` prints, writes and draws: the statistics of a recording beside
those of a rendering (--compare), the [sensor] table to paste into a config, and a PNG of four
panels (noise against level, dot widths, dot peak signal-to-noise ratios, dots per area by depth),
the recording in orange, the rendering in blue. Pure numpy and OpenCV.
"""

from __future__ import annotations

import numpy as np

from capture.photon_transfer import Estimate
from capture.sensor_fit import DEPTH_EDGES, SensorFit, SensorStatistics
from dotsim.config_schema import toml_text
from dotsim.sensor.model import FWHM_PER_SIGMA

PANEL = (440, 300)  # width, height of a chart, px
MARGIN = (60, 40, 30, 20)  # left, bottom, top, right, px
BACKGROUND = (40, 40, 40)
TEXT = (235, 235, 235)
RECORDING = (40, 150, 255)  # orange (BGR)
RENDERING = (255, 160, 60)  # blue
MIN_DEPTH_PIXELS = 1000  # a depth bin is listed from this many pixels of that depth on
ORDER = ("read_noise", "shot_noise", "bit_depth", "exposure", "auto_percentile", "auto_target", "blur_sigma",
         "projector_aperture", "projector_focus", "speckle_contrast", "speckle_grain")


def _estimate(estimate: Estimate | None, digits: int = 3) -> str:
    return "-" if estimate is None else estimate.text(digits)


def _dots_per_area(stats: SensorStatistics) -> np.ndarray:
    """Dots per 1000 px in each depth bin (nan where the bin has no pixel)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(stats.depth_pixels > 0, 1000 * stats.depth_dots / stats.depth_pixels, np.nan)


def _rows(stats: SensorStatistics) -> list[tuple[str, str]]:
    read, shot = stats.read_noise, stats.shot_noise
    full_scale = 2**stats.bit_depth - 1 if stats.bit_depth else None
    rows = [("read noise (full scale 1)", _estimate(read)
             + (f" = {read.value * full_scale:.3g} DN" if full_scale else "")),
            ("noise at the black level", _estimate(stats.dark_noise)),
            ("shot noise at full scale", _estimate(shot))]
    if shot.value > 0:
        electrons = 1 / shot.value**2
        gain = f"full well {electrons:.4g} e-, read noise {read.value * electrons:.3g} e-"
        rows.append(("photo-electrons (EMVA 1288)", (f"system gain K {shot.value**2 * full_scale:.3g} DN/e-, "
                                                     if full_scale else "") + gain))
    clipped = stats.black.value == 0 and stats.black.error == 0
    rows.append(("black level", "0 (the sensor clips there)" if clipped
                 else f"<= {_estimate(stats.black)} (its darkest pixels)"))
    rows.append(("saturation (clipped, left out)", f"{stats.saturation:.4g}: {stats.saturated} samples, "
                 f"{100 * stats.saturated_share:.2f}% of the projector-on samples"
                 if stats.saturation is not None else "not reached"))
    rows.append(("bit depth", str(stats.bit_depth) if stats.bit_depth else "more than 16 or not quantised"))
    rows.append(("99th percentile level", f"{stats.exposure_level:.3g}"))
    rows.append(("dot FWHM, px", f"{_estimate(stats.dot_fwhm)} ({stats.dots} isolated dots on flat "
                 f"regions of {stats.dots_detected})"))
    rows.append(("dot brightness contrast", _estimate(stats.contrast)))
    rows.append(("dot peak SNR, one frame", f"median {np.median(stats.snr):.3g}, 10% below "
                 f"{np.percentile(stats.snr, 10):.3g}"))
    rows.append(("ambient / projector light", _estimate(stats.ambient_ratio)))
    per_area = _dots_per_area(stats)
    for k, value in enumerate(per_area):
        if stats.depth_pixels[k] >= MIN_DEPTH_PIXELS:
            rows.append((f"dots per 1000 px, {DEPTH_EDGES[k]:g}-{DEPTH_EDGES[k + 1]:g} m", f"{value:.3g}"))
    return rows


def _describe(stats: SensorStatistics) -> str:
    r = stats.recording
    how = "photon transfer over time" if stats.method == "temporal" else "flat regions of single frames"
    return (f"{r.name} ({r.kind}; {len(r.frame_counts)} scene(s), {sum(r.frame_counts)} projector-on "
            f"frame(s), {r.size[0]} x {r.size[1]} px): {how}")


def report_text(stats: SensorStatistics, fitted: SensorFit, reference: SensorStatistics | None = None) -> str:
    """The statistics (beside the rendering's with `reference`) and the fitted [sensor] values."""
    lines = [f"recording: {_describe(stats)}"]
    if reference is not None:
        lines.append(f"rendering: {_describe(reference)}")
    columns = [dict(_rows(stats))] + ([dict(_rows(reference))] if reference is not None else [])
    names = list(dict.fromkeys(name for column in columns for name in column))
    width = max(len(name) for name in names) + 2
    cell = max(len(value) for value in columns[0].values()) + 2
    if reference is not None:
        lines.append(f"{'':{width}}{'recording':{cell}}rendering")
    lines += [f"{name:{width}}" + "".join(f"{column.get(name, '-'):{cell}}" for column in columns).rstrip()
              for name in names]
    lines += [f"note: {note}" for note in stats.notes]
    lines.append("for your config:")
    lines += ["  " + line for line in sensor_toml(fitted).splitlines()[1:]]
    return "\n".join(lines)


def sensor_toml(fitted: SensorFit, header: str = "") -> str:
    """The fitted values as a [sensor] table, each with its error and how it was found as a comment,
    and with projector-off frames a [lighting] table: the ambient_ratio range of the recording's scenes
    (docs/CAPTURE.md "Rooms lit as real rooms are")."""
    lines = [f"# {line}" for line in header.splitlines()] + ["[sensor]"]
    for key in ORDER:
        if key not in fitted.values:
            continue
        comment = []
        if key in fitted.errors:
            comment.append(f"± {fitted.errors[key]:.2g}")
        if key in fitted.notes:
            comment.append(fitted.notes[key])
        line = f"{key} = {toml_text(fitted.values[key])}"
        lines.append(f"{line}  # {'; '.join(comment)}" if comment else line)
    if "blur_sigma" not in fitted.values:
        lines.append("# blur_sigma: run with --compare DATASET (a rendering of your config) to set it")
    if fitted.ambient_ratio is not None:
        lines += ["[lighting]", f"ambient_ratio = {toml_text(list(fitted.ambient_ratio))}  # the lowest and "
                  "highest of the recording's scenes (projector-off over on - off where the projector "
                  "reaches)"]
    return "\n".join(lines) + "\n"


def _put(canvas: np.ndarray, text: str, x: int, y: int, scale: float = 0.4) -> None:
    import cv2

    cv2.putText(canvas, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, TEXT, 1, cv2.LINE_AA)


def _chart(canvas: np.ndarray, x0: int, y0: int, title: str, xlabel: str, series: list, x_range,
           y_range) -> None:
    """One panel: each series (xs, ys, BGR, "line" | "points" | "bars") in data units on the ranges."""
    import cv2

    left, bottom, top, right = MARGIN
    width, height = PANEL[0] - left - right, PANEL[1] - top - bottom
    origin = (x0 + left, y0 + top + height)

    def pixel(x, y):
        fx = (np.asarray(x, np.float64) - x_range[0]) / (x_range[1] - x_range[0])
        fy = (np.asarray(y, np.float64) - y_range[0]) / (y_range[1] - y_range[0])
        return origin[0] + fx * width, origin[1] - np.clip(fy, 0, 1) * height

    _put(canvas, title, x0 + left, y0 + 16, 0.42)
    cv2.rectangle(canvas, (origin[0], origin[1] - height), (origin[0] + width, origin[1]), TEXT, 1)
    for fraction in (0.0, 0.5, 1.0):
        _put(canvas, f"{x_range[0] + fraction * (x_range[1] - x_range[0]):.3g}",
             origin[0] + int(fraction * width) - 10, origin[1] + 15, 0.35)
        _put(canvas, f"{y_range[0] + fraction * (y_range[1] - y_range[0]):.3g}", x0 + 4,
             origin[1] - int(fraction * height) + 4, 0.35)
    _put(canvas, xlabel, origin[0] + width // 2 - 40, origin[1] + 32, 0.38)
    for xs, ys, colour, kind in series:
        finite = np.isfinite(xs) & np.isfinite(ys)
        px, py = pixel(np.asarray(xs)[finite], np.asarray(ys)[finite])
        points = np.stack([px, py], axis=1).round().astype(np.int32)
        if kind == "line" and len(points) > 1:
            cv2.polylines(canvas, [points], False, colour, 2, cv2.LINE_AA)
        elif kind == "points":
            for point in points:
                cv2.circle(canvas, tuple(int(v) for v in point), 3, colour, -1, cv2.LINE_AA)
        elif kind == "bars":
            step = width / max(len(points), 1)
            for point in points:
                cv2.rectangle(canvas, (int(point[0] - step / 2) + 1, int(point[1])),
                              (int(point[0] + step / 2) - 1, origin[1]), colour, 1)


def _histogram(values: np.ndarray, edges: np.ndarray) -> np.ndarray:
    counts, _ = np.histogram(values, edges)
    return counts / max(counts.sum(), 1)


def draw_report(stats: SensorStatistics, reference: SensorStatistics | None = None) -> np.ndarray:
    """The four panels (module docstring) as a BGR image."""
    both = [(stats, RECORDING, 1.0)]
    if reference is not None:
        # the rendering's widths in the recording's pixels (same field of view)
        both.append((reference, RENDERING, stats.recording.size[0] / reference.recording.size[0]))
    canvas = np.full((2 * PANEL[1] + 40, 2 * PANEL[0], 3), BACKGROUND, np.uint8)
    legend = "orange: the recording" + ("; blue: the rendering" if reference is not None else "")
    _put(canvas, legend, 10, 2 * PANEL[1] + 28, 0.45)
    top_level = max(max(s.noise.levels.max() for s, _, _ in both), 1e-3)
    noise = []
    for s, colour, _ in both:
        curve = np.linspace(0, top_level, 50)
        noise += [(s.noise.levels, np.sqrt(np.maximum(s.noise.variances, 0)), colour, "points"),
                  (curve, s.noise.sigma(curve), colour, "line")]
    top_sigma = max(float(np.nanmax(ys)) for _, ys, _, _ in noise) * 1.1
    _chart(canvas, 0, 0, "noise (one frame) against level", "level (full scale 1)", noise, (0, top_level),
           (0, top_sigma))
    widths = [FWHM_PER_SIGMA * s.dot_sigma.value * ratio for s, _, ratio in both]
    edges = np.linspace(0, 2.5 * max(widths), 41)
    centres = 0.5 * (edges[1:] + edges[:-1])
    fwhm = [(centres, _histogram(s.dot_sigmas * FWHM_PER_SIGMA * ratio, edges), colour, "line")
            for s, colour, ratio in both]
    _chart(canvas, PANEL[0], 0, "dot FWHM (recording px): share of dots", "FWHM px", fwhm, (0, edges[-1]),
           (0, max(float(h.max()) for _, h, _, _ in fwhm) * 1.1))
    top_snr = max(float(np.percentile(s.snr, 99)) for s, _, _ in both) * 1.1
    edges = np.linspace(0, top_snr, 41)
    centres = 0.5 * (edges[1:] + edges[:-1])
    snr = [(centres, _histogram(s.snr, edges), colour, "line") for s, colour, _ in both]
    _chart(canvas, 0, PANEL[1], "dot peak SNR in one frame: share of dots", "peak / noise", snr, (0, top_snr),
           (0, max(float(h.max()) for _, h, _, _ in snr) * 1.1))
    middles = 0.5 * (DEPTH_EDGES[1:] + DEPTH_EDGES[:-1])
    density = [(middles, _dots_per_area(s), colour, "line") for s, colour, _ in both]
    known = [v for _, ys, _, _ in density for v in ys if np.isfinite(v)]
    _chart(canvas, PANEL[0], PANEL[1], "dots per 1000 px by depth" + ("" if known else " (depth not known)"),
           "depth m", density, (0, DEPTH_EDGES[-1]), (0, max(known) * 1.1 if known else 1.0))
    return canvas
