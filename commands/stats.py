"""`dotsim stats DIR`: what a dataset's frames cover. Printed, drawn (PNG) and written (JSON).

- depth: histograms of valid GT depth (finite, > 0, within the rig's max_depth) over all pixels and
  over the visible ones (visibility = 1: where the network learns), the share of visible pixels beyond
  1 m and 2 m and their median;
- disparity (d = fx b / z, camera px) of the same pixels;
- the share of pixels that are visible and that are on depth edges;
- pattern coverage: where in the projector image the visible pixels' light comes from (each visible
  pixel's point projected into the projector: its column and row), per projector column and row and
  per region of a grid over the projector image. GigaDepth's authors note that a network fails where
  its training data barely shows part of the pattern: such regions are listed, apart from the regions
  the camera never sees at any depth (its field of view is narrower than the projector's).

Frames are read only through dotsim.dataset's reader. Pure numpy + OpenCV.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from dotsim import dataset as ds
from dotsim.command_options import add_output
from dotsim.file_io import atomic_write_json
from dotsim.frame_source import FrameSource, open_source
from dotsim.images import write_image
from dotsim.option_types import integer
from dotsim.rig.geometry import Rig, backproject, is_ground_truth, project_to_projector

STATS_CHANNELS = ("depth", "visibility", "edge")
DEPTH_STEP = 0.01  # m: the fine histogram the shares and medians are read from
DISPARITY_STEP = 0.5  # camera px
THRESHOLDS_M = (1.0, 2.0)
REGIONS = (8, 8)  # (rows, columns) of the grid over the projector image
THIN_SHARE = 0.1  # a region with less than this share of the mean region's lit pixels is "barely shown"
NEAREST_VIEW_M = 0.2  # the nearest surface considered when asking which regions the camera can see


@dataclass
class CoverageStats:
    """Running counts over the frames of a dataset (add_frame), summarised by summary()."""

    rig: Rig
    frames: int = 0
    pixels: int = 0
    valid: int = 0
    visible: int = 0
    edge: int = 0
    visible_edge: int = 0
    depth_all: np.ndarray = field(default=None)
    depth_visible: np.ndarray = field(default=None)
    disparity_visible: np.ndarray = field(default=None)
    columns: np.ndarray = field(default=None)
    rows: np.ndarray = field(default=None)
    regions: np.ndarray = field(default=None)
    reachable: np.ndarray = field(default=None)

    def __post_init__(self):
        depth_bins = math.ceil(self.rig.max_depth / DEPTH_STEP)
        self.depth_all = np.zeros(depth_bins, np.int64)
        self.depth_visible = np.zeros(depth_bins, np.int64)
        self.disparity_visible = np.zeros(math.ceil(self.max_disparity / DISPARITY_STEP) + 1, np.int64)
        self.columns = np.zeros(self.rig.projector.width, np.int64)
        self.rows = np.zeros(self.rig.projector.height, np.int64)
        self.regions = np.zeros(REGIONS, np.int64)
        self.reachable = reachable_regions(self.rig)

    @property
    def max_disparity(self) -> float:
        """The disparity histogram's upper end: a surface 5 cm away."""
        return self.rig.camera.fx * abs(self.rig.baseline) / 0.05

    def add_frame(self, frame: dict[str, np.ndarray]) -> None:
        """Count one frame (channels depth, visibility, edge)."""
        depth = np.asarray(frame["depth"], np.float64)
        valid = is_ground_truth(depth, self.rig.max_depth)
        visible = valid & (frame["visibility"] > 0)
        edge = frame["edge"] > 0
        self.frames += 1
        self.pixels += depth.size
        self.valid += int(valid.sum())
        self.visible += int(visible.sum())
        self.edge += int(edge.sum())
        self.visible_edge += int((edge & visible).sum())
        _accumulate(self.depth_all, depth[valid], DEPTH_STEP)
        _accumulate(self.depth_visible, depth[visible], DEPTH_STEP)
        disparity = self.rig.camera.fx * abs(self.rig.baseline) / depth[visible]
        _accumulate(self.disparity_visible, disparity, DISPARITY_STEP)
        xp, yp, _ = project_to_projector(backproject(np.where(visible, depth, np.nan), self.rig.camera),
                                         self.rig)
        proj = self.rig.projector
        inside = visible & (xp >= -0.5) & (xp < proj.width - 0.5) & (yp >= -0.5) & (yp < proj.height - 0.5)
        col = np.clip(np.rint(xp[inside]).astype(np.int64), 0, proj.width - 1)
        row = np.clip(np.rint(yp[inside]).astype(np.int64), 0, proj.height - 1)
        self.columns += np.bincount(col, minlength=proj.width)
        self.rows += np.bincount(row, minlength=proj.height)
        np.add.at(self.regions, (row * REGIONS[0] // proj.height, col * REGIONS[1] // proj.width), 1)

    def summary(self) -> dict:
        """JSON-safe figures (shares of pixels, depths in m, disparities in camera px)."""
        share = _share
        vis = self.depth_visible
        seen = self.regions[self.reachable]
        mean_region = seen.mean() if seen.size else 0.0
        thin = np.nonzero(self.reachable & (self.regions < THIN_SHARE * mean_region))
        thin = [[int(r), int(c)] for r, c in zip(*thin, strict=True)] if mean_region else []
        return {
            "frames": self.frames,
            "pixels": self.pixels,
            "share_valid_depth": share(self.valid, self.pixels),
            "share_visible": share(self.visible, self.pixels),
            "share_edge": share(self.edge, self.pixels),
            "share_edge_of_visible": share(self.visible_edge, self.visible),
            "visible": {f"share_beyond_{t:g}m": share(_count_beyond(vis, t), self.visible)
                        for t in THRESHOLDS_M}
            | {"median_m": _median(vis, DEPTH_STEP)},
            "valid": {f"share_beyond_{t:g}m": share(_count_beyond(self.depth_all, t), self.valid)
                      for t in THRESHOLDS_M}
            | {"median_m": _median(self.depth_all, DEPTH_STEP)},
            "visible_disparity_px": {"median": _median(self.disparity_visible, DISPARITY_STEP),
                                     "max": _top(self.disparity_visible, DISPARITY_STEP)},
            "pattern_coverage": {
                "share_columns_lit": share(int((self.columns > 0).sum()), self.columns.size),
                "share_rows_lit": share(int((self.rows > 0).sum()), self.rows.size),
                "region_grid": list(REGIONS),
                "region_lit_pixels": self.regions.tolist(),
                "regions_in_camera_view": int(self.reachable.sum()),
                "regions_barely_shown": thin,
                "barely_shown_means": f"in the camera's view at some depth from {NEAREST_VIEW_M:g} m to "
                                      f"max_depth, with fewer than {THIN_SHARE:g} x the mean lit pixels of "
                                      "such regions",
            },
            "histograms": {
                "depth_step_m": DEPTH_STEP, "depth_all": _trimmed(self.depth_all),
                "depth_visible": _trimmed(vis),
                "disparity_step_px": DISPARITY_STEP, "disparity_visible": _trimmed(self.disparity_visible),
            },
        }


def reachable_regions(rig: Rig) -> np.ndarray:
    """bool REGIONS grid: the projector regions some camera pixel sees, for a surface at some depth
    from NEAREST_VIEW_M to the rig's max_depth (the rest of the pattern is outside the camera's view
    whatever the scene: the camera's field is narrower than the projector's)."""
    cam, proj = rig.camera, rig.projector
    step = max(1, min(cam.width, cam.height) // 64)
    seen = np.zeros(REGIONS, bool)
    for depth in np.geomspace(NEAREST_VIEW_M, rig.max_depth, 24):
        plane = np.full((cam.height, cam.width), depth)
        xp, yp, _ = project_to_projector(backproject(plane, cam)[::step, ::step], rig)
        inside = (xp >= -0.5) & (xp < proj.width - 0.5) & (yp >= -0.5) & (yp < proj.height - 0.5)
        col = np.clip(np.rint(xp[inside]).astype(np.int64), 0, proj.width - 1)
        row = np.clip(np.rint(yp[inside]).astype(np.int64), 0, proj.height - 1)
        seen[row * REGIONS[0] // proj.height, col * REGIONS[1] // proj.width] = True
    return seen


def _share(count: int, total: int) -> float:
    return count / total if total else 0.0


def _accumulate(hist: np.ndarray, values: np.ndarray, step: float) -> None:
    """Add values to a histogram of bins [k step, (k + 1) step); the last bin takes any beyond."""
    index = np.minimum((values / step).astype(np.int64), hist.size - 1)
    hist += np.bincount(index, minlength=hist.size)


def _count_beyond(hist: np.ndarray, value: float) -> int:
    """Count of values >= `value`, exact when `value` is a bin edge (the shares' 1 m and 2 m are)."""
    return int(hist[round(value / DEPTH_STEP):].sum())


def _median(hist: np.ndarray, step: float) -> float | None:
    """The median of a histogram's values, linearly within its bin (None when empty: JSON's null)."""
    total = hist.sum()
    if not total:
        return None
    cum = np.cumsum(hist)
    k = int(np.searchsorted(cum, total / 2))
    before = cum[k - 1] if k else 0
    return float((k + (total / 2 - before) / hist[k]) * step)


def _top(hist: np.ndarray, step: float) -> float | None:
    nonzero = np.nonzero(hist)[0]
    return float((nonzero[-1] + 1) * step) if nonzero.size else None


def _value(value: float | None, unit: str, digits: int = 2) -> str:
    """A median or maximum as printed: "n/a" where there was nothing to take it of.

    >>> _value(1.234, "m"), _value(None, "px")
    ('1.23 m', 'n/a')
    """
    return "n/a" if value is None else f"{value:.{digits}f} {unit}"


def _trimmed(hist: np.ndarray) -> list[int]:
    """The histogram without its empty tail (JSON stays small)."""
    nonzero = np.nonzero(hist)[0]
    return hist[: nonzero[-1] + 1].tolist() if nonzero.size else []


def dataset_stats(source: FrameSource, max_frames: int = 0) -> CoverageStats:
    """CoverageStats over the frames of a data source (dotsim.frame_source.open_source: one split of a
    dataset folder or of its export), the first `max_frames` of them (0: all)."""
    missing = [c for c in STATS_CHANNELS if c not in source.channels]
    if missing:
        raise ds.FormatError(f"{source.name}: stores {', '.join(source.channels)}, no ground truth "
                             f"({', '.join(missing)}): nothing for stats to count (a capture: "
                             "`dotsim show` draws its passes)")
    stats = CoverageStats(source.rig)
    for ref in source.first(max_frames).frames:
        stats.add_frame(ref.read(STATS_CHANNELS))
    return stats


def format_summary(s: dict) -> str:
    """The printed lines of a summary()."""
    vis, val, cov = s["visible"], s["valid"], s["pattern_coverage"]
    thin = cov["regions_barely_shown"]
    return "\n".join([
        f"{s['frames']} frame(s), {s['pixels']} pixels: valid depth {s['share_valid_depth']:.1%}, "
        f"visible {s['share_visible']:.1%}, on edges {s['share_edge']:.1%} "
        f"({s['share_edge_of_visible']:.1%} of the visible)",
        f"visible pixels: {vis['share_beyond_1m']:.1%} beyond 1 m, {vis['share_beyond_2m']:.1%} beyond 2 m, "
        f"median {_value(vis['median_m'], 'm')}; disparity median "
        f"{_value(s['visible_disparity_px']['median'], 'px', 1)}, "
        f"max {_value(s['visible_disparity_px']['max'], 'px', 1)}",
        f"all valid depth: {val['share_beyond_1m']:.1%} beyond 1 m, {val['share_beyond_2m']:.1%} beyond 2 m, "
        f"median {_value(val['median_m'], 'm')}",
        f"pattern coverage: {cov['share_columns_lit']:.1%} of projector columns and "
        f"{cov['share_rows_lit']:.1%} of rows lit on visible pixels; of the {cov['region_grid'][0]} x "
        f"{cov['region_grid'][1]} projector regions {cov['regions_in_camera_view']} are ever in the "
        f"camera's view and {len(thin)} of those barely shown "
        f"({cov['barely_shown_means']})" + (f": (row, column) {thin}" if thin else ""),
    ])


# Drawing: three panels side by side (depth, disparity, projector regions), grey background.
PANEL = (360, 220)  # width, height of a histogram panel, px
BACKGROUND = (40, 40, 40)
TEXT = (235, 235, 235)
ALL_COLOUR = (150, 150, 150)
VISIBLE_COLOUR = (60, 180, 255)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def _bars(canvas: np.ndarray, x0: int, y0: int, series, bins: int, top: float, unit: str, title: str) -> None:
    """Histograms (list of (counts over [0, top], BGR)) as bars, each normalised to its own peak."""
    w, h = PANEL
    plot_h = h - 50
    cv2.putText(canvas, title, (x0, y0 + 14), FONT, 0.42, TEXT, 1, cv2.LINE_AA)
    base = y0 + 20 + plot_h
    for counts, colour in series:
        coarse = np.add.reduceat(counts, np.linspace(0, counts.size, bins + 1).astype(int)[:-1]) \
            if counts.size >= bins else np.pad(counts, (0, bins - counts.size))
        peak = max(int(coarse.max()), 1)
        for k, c in enumerate(coarse):
            bx = x0 + k * w // bins
            cv2.rectangle(canvas, (bx, base - int(plot_h * c / peak)), (bx + max(w // bins - 2, 1), base),
                          colour, -1 if colour == VISIBLE_COLOUR else 1)
    cv2.line(canvas, (x0, base), (x0 + w, base), TEXT, 1)
    for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
        cv2.putText(canvas, f"{frac * top:.3g}", (x0 + int(frac * (w - 20)), base + 14), FONT, 0.36, TEXT, 1,
                    cv2.LINE_AA)
    cv2.putText(canvas, unit, (x0 + w - 60, base + 28), FONT, 0.36, TEXT, 1, cv2.LINE_AA)


def draw(stats: CoverageStats, title: str) -> np.ndarray:
    """The PNG: depth and disparity histograms (grey outline: all valid pixels, orange: visible; each
    scaled to its own peak), and the projector regions' lit pixels (brighter = more; red = barely shown)."""
    w, h = PANEL
    canvas = np.full((h + 70, 3 * (w + 20) + 20, 3), BACKGROUND, np.uint8)
    cv2.putText(canvas, title, (10, 18), FONT, 0.45, TEXT, 1, cv2.LINE_AA)
    depth_top = 8.0 if stats.rig.max_depth > 8 else stats.rig.max_depth
    cut = round(depth_top / DEPTH_STEP)
    _bars(canvas, 10, 30, [(stats.depth_all[:cut], ALL_COLOUR), (stats.depth_visible[:cut], VISIBLE_COLOUR)],
          64, depth_top, "depth m", "depth: grey all valid, orange visible")
    disparity_top = 10 * math.ceil(stats.rig.camera.fx * abs(stats.rig.baseline) / 0.25 / 10)  # to 25 cm
    cut = round(disparity_top / DISPARITY_STEP)
    _bars(canvas, w + 30, 30, [(stats.disparity_visible[:cut], VISIBLE_COLOUR)], 64, disparity_top,
          "disparity px", "disparity of visible pixels")
    grid = stats.regions.astype(np.float64)
    mean = grid[stats.reachable].mean() if stats.reachable.any() else 0.0
    side = h - 40
    cells = np.zeros((*REGIONS, 3), np.uint8)
    level = np.clip(grid / max(grid.max(), 1), 0, 1)
    cells[...] = (level * 255).astype(np.uint8)[..., None]
    cells[stats.reachable & (grid < THIN_SHARE * mean)] = (40, 40, 200)
    cells[~stats.reachable] = (90, 60, 60)
    image = cv2.resize(cells, (side, side), interpolation=cv2.INTER_NEAREST)
    x0 = 2 * (w + 20) + 20
    canvas[50 : 50 + side, x0 : x0 + side] = image
    cv2.putText(canvas, f"projector regions {REGIONS[0]}x{REGIONS[1]}: lit pixels", (x0, 44), FONT, 0.42,
                TEXT, 1, cv2.LINE_AA)
    cv2.putText(canvas, "white = most, red = barely shown, blue = never in view", (x0, 50 + side + 16), FONT,
                0.38, TEXT, 1,
                cv2.LINE_AA)
    s = stats.summary()
    line = (f"visible: {s['share_visible']:.1%} of pixels, {s['visible']['share_beyond_1m']:.1%} beyond 1 m, "
            f"{s['visible']['share_beyond_2m']:.1%} beyond 2 m, "
            f"median {_value(s['visible']['median_m'], 'm')}; "
            f"edges {s['share_edge']:.1%}")
    cv2.putText(canvas, line, (10, h + 60), FONT, 0.42, TEXT, 1, cv2.LINE_AA)
    return canvas


def run(args: argparse.Namespace) -> int:
    stats = dataset_stats(open_source(args.path, args.split), args.max_frames)
    summary = stats.summary()
    output = Path(args.output)
    json_path = Path(args.json) if args.json else output.with_suffix(".json")
    write_image(output, draw(stats, f"{args.path} (split {args.split}, {stats.frames} frames)"))
    atomic_write_json(json_path, {"dataset": str(args.path), "split": args.split, **summary})
    print(format_summary(summary))
    if not stats.visible:
        print(f"no pixel of the {stats.frames} frame(s) is visible (visibility = 1 nowhere): nothing for "
              "training to learn from; see docs/CONFIG_GUIDE.md 'Shaping the depth distribution'",
              file=sys.stderr)
    print(f"wrote {output} and {json_path}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "stats", help="histograms of depth and disparity, visible and edge shares, pattern coverage",
        description="What a dataset's frames cover: histograms of valid GT depth and of disparity (all "
        "valid pixels and the visible ones, visibility = 1, where the network learns), the share of "
        "visible and of edge pixels, the share of visible pixels beyond 1 m and 2 m, and pattern "
        "coverage: which projector columns, rows and regions (an 8 x 8 grid) the visible pixels are lit "
        "from; regions the camera can see at some depth but with under a tenth of the mean such region's "
        "lit pixels are listed as barely shown, apart from those it never sees (its field is narrower). "
        "Prints a summary, draws a PNG and writes the figures as JSON.")
    parser.add_argument("path", metavar="DIR", help="sealed dotsim dataset (or its `dotsim export` shards)")
    parser.add_argument("--split", default="all", help="scene split: all (default), train or test")
    add_output(parser, "PNG to draw (default: stats.png)", metavar="PNG", required=False, old=("--output",),
               dest="output", default="stats.png")
    parser.add_argument("--json", default=None, metavar="FILE",
                        help="JSON to write (default: the PNG's name with .json)")
    parser.add_argument("--max-frames", type=integer(0), default=0, metavar="N",
                        help="the first N frames only (default 0: all)")
    parser.set_defaults(func=run, errors={ds.FormatError: 1})
    return parser
