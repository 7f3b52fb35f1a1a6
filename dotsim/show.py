"""`dotsim show`: a labelled contact sheet of every pass of every frame of a scene (PNG).

Rows are frames, columns the stored passes (docs/FORMAT.md): IR, ambient, flood as grey images,
depth, projector column and disparity colour-mapped (turbo) with a colour bar in their units
under the grid, the visibility and edge masks white where set. Black in a colour-mapped tile
means no value there (no hit / invalid). numpy + OpenCV only.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dotsim import dataset as ds
from dotsim.images import write_image

COLUMNS = ("ir", "ambient", "flood", "depth", "visibility", "edge", "projector_column", "disparity")
TITLES = {"ir": "IR", "ambient": "ambient", "flood": "flood", "depth": "depth",
          "visibility": "visibility", "edge": "edge", "projector_column": "projector column",
          "disparity": "disparity"}
UNITS = {"depth": "m", "projector_column": "projector px", "disparity": "camera px"}
COLOUR_MAPPED = ("depth", "projector_column", "disparity")
FONT = cv2.FONT_HERSHEY_SIMPLEX
TEXT_SCALE = 0.45
LINE = 18  # text line height, px
GAP = 6  # between tiles, px
LABEL_WIDTH = 70  # left column with the frame labels, px
BAR_HEIGHT = 14
BACKGROUND = (40, 40, 40)
TEXT_COLOUR = (235, 235, 235)


@dataclass
class SheetLayout:
    """Where each tile of a contact sheet is: (frame, channel) -> (x, y, width, height)."""

    tiles: dict[tuple[int, str], tuple[int, int, int, int]]
    tile_size: tuple[int, int]  # (width, height)


def _grey(image: np.ndarray, scale: float) -> np.ndarray:
    """Linear grey: value / scale clipped to [0, 1] -> 0..255; non-finite -> black."""
    x = np.where(np.isfinite(image), image.astype(np.float64) / scale, 0.0)
    return np.repeat(np.rint(np.clip(x, 0, 1) * 255).astype(np.uint8)[..., None], 3, axis=2)


def colourise(image: np.ndarray, low: float, high: float) -> np.ndarray:
    """Turbo colour map of image over [low, high] (BGR uint8); non-finite pixels black."""
    finite = np.isfinite(image)
    span = high - low if high > low else 1.0
    x = np.where(finite, (image.astype(np.float64) - low) / span, 0.0)
    bgr = cv2.applyColorMap(np.rint(np.clip(x, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_TURBO)
    bgr[~finite] = 0
    return bgr


def _finite_range(arrays: list[np.ndarray]) -> tuple[float, float]:
    values = np.concatenate([a[np.isfinite(a)].ravel().astype(np.float64) for a in arrays])
    if values.size == 0:
        return 0.0, 1.0
    return float(values.min()), float(values.max())


def _grey_scale(frames: list[dict], name: str) -> float:
    """Display scale of a grey pass: IR is already in [0, 1] of full scale; ambient and flood share
    the flood pass's 99th percentile so their brightness can be compared tile to tile."""
    if name == "ir":
        return 1.0
    source = "flood" if "flood" in frames[0] else name
    values = np.concatenate([f[source][np.isfinite(f[source])].ravel() for f in frames]).astype(np.float64)
    scale = float(np.percentile(values, 99)) if values.size else 1.0
    return scale if scale > 0 else 1.0


def _text(img, text, x, y, colour=TEXT_COLOUR, scale=TEXT_SCALE):
    cv2.putText(img, text, (int(x), int(y)), FONT, scale, colour, 1, cv2.LINE_AA)


def _fmt(v: float) -> str:
    return f"{v:.4g}"


def contact_sheet(frames: list[dict[str, np.ndarray]], title: str, tile_width: int = 320,
                  frame_labels: list[str] | None = None) -> tuple[np.ndarray, SheetLayout]:
    """Draw the sheet (BGR uint8) for frames (channel -> (H, W) array, as read_frame returns).

    Columns follow COLUMNS, keeping the channels the frames have. Returns the image and where
    each tile is, so callers (and tests) can find a pass in it.
    """
    if not frames:
        raise ValueError("contact_sheet needs at least one frame")
    if int(tile_width) < 16:
        raise ValueError(f"tile width must be at least 16 px, got {tile_width}")
    channels = [c for c in COLUMNS if c in frames[0]]
    if not channels:
        raise ValueError(f"frames have none of the channels {list(COLUMNS)}")
    h, w = frames[0][channels[0]].shape
    tile_w = int(tile_width)
    tile_h = max(1, round(tile_w * h / w))
    ranges = {c: _finite_range([f[c] for f in frames]) for c in channels if c in COLOUR_MAPPED}
    scales = {c: _grey_scale(frames, c) for c in channels if c in ("ir", "ambient", "flood")}
    labels = frame_labels or [f"frame {k}" for k in range(len(frames))]

    top = 2 * LINE + GAP  # title line, column headers
    grid_w = len(channels) * (tile_w + GAP)
    legend_h = (LINE + BAR_HEIGHT + LINE) * len(ranges) + 2 * LINE + GAP
    sheet_h = top + len(frames) * (tile_h + GAP) + legend_h
    sheet_w = LABEL_WIDTH + grid_w + GAP
    sheet = np.full((sheet_h, sheet_w, 3), BACKGROUND, np.uint8)
    _text(sheet, title, GAP, LINE - 4)

    tiles = {}
    for j, name in enumerate(channels):
        x = LABEL_WIDTH + j * (tile_w + GAP)
        header = TITLES[name] + (f" /{_fmt(scales[name])}" if name in ("ambient", "flood") else "")
        _text(sheet, header, x, 2 * LINE - 4)
        for k, frame in enumerate(frames):
            y = top + k * (tile_h + GAP)
            image = frame[name]
            if name in COLOUR_MAPPED:
                tile = colourise(image, *ranges[name])
            elif name in ds.MASK_CHANNELS:
                tile = _grey(image, 1.0)
            else:
                tile = _grey(image, scales[name])
            tile = cv2.resize(tile, (tile_w, tile_h), interpolation=cv2.INTER_AREA)
            sheet[y:y + tile_h, x:x + tile_w] = tile
            tiles[(k, name)] = (x, y, tile_w, tile_h)
    for k, label in enumerate(labels):
        _text(sheet, label, GAP, top + k * (tile_h + GAP) + tile_h // 2)

    y = top + len(frames) * (tile_h + GAP) + LINE
    for name, (low, high) in ranges.items():
        _text(sheet, f"{TITLES[name]} ({UNITS[name]}), black = none", LABEL_WIDTH, y)
        bar_w = min(grid_w - GAP, 512)
        ramp = np.linspace(low, high, bar_w)[None, :].repeat(BAR_HEIGHT, axis=0)
        sheet[y + 4:y + 4 + BAR_HEIGHT, LABEL_WIDTH:LABEL_WIDTH + bar_w] = colourise(ramp, low, high)
        for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
            tx = LABEL_WIDTH + int(frac * (bar_w - 1))
            _text(sheet, _fmt(low + frac * (high - low)), min(tx, sheet_w - 50), y + BAR_HEIGHT + LINE)
        y += LINE + BAR_HEIGHT + LINE
    _text(sheet, "IR: 0..1 of full scale; ambient, flood: divided by the flood's 99th percentile; "
                 "masks: white = 1", GAP, y)
    return sheet, SheetLayout(tiles=tiles, tile_size=(tile_w, tile_h))


def load_for_sheet(path: str | Path, scene_index: int | None = None,
                   verify: bool = True) -> tuple[list[dict], str, list[str]]:
    """Frames, a title and row labels for PATH: a dataset dir (scene `scene_index`, default the
    first), a scene dir, or one frame EXR."""
    path = Path(path)
    if path.is_file():
        frame = ds.read_frame(path, verify=verify)
        h, w = next(iter(frame.values())).shape
        return [frame], f"{path}  ({w} x {h})", [path.stem]
    if (path / ds.SCENE_FILE).is_file():
        scene_path = path
    elif path.is_dir():
        scenes = ds.complete_scenes(path)
        if not scenes:
            raise ds.FormatError(f"{path}: no complete scene found (neither a scene directory with "
                                 f"{ds.SCENE_FILE}, nor a dataset with shard_*/scene_* inside)")
        if scene_index is None:
            scene_path = scenes[0][1]
        else:
            found = dict(scenes)
            if scene_index not in found:
                raise ds.FormatError(f"{path}: no scene {scene_index}; it has scenes "
                                     f"{scenes[0][0]}..{scenes[-1][0]} ({len(scenes)} in all)")
            scene_path = found[scene_index]
    else:
        raise ds.FormatError(f"{path}: no such file or directory")
    scene = ds.read_scene(scene_path, verify=verify)
    meta = scene.meta
    h, w = ds.camera_size(meta)
    title = (f"{scene_path}  scene {meta['scene_index']} ({meta['split']}), rig "
             f"{meta['rig'].get('name', '?')}, {w} x {h}, format {meta['format_version']}")
    return scene.frames, title, [f"frame {k}" for k in range(len(scene.frames))]


def run(args: argparse.Namespace) -> int:
    try:
        frames, title, labels = load_for_sheet(args.path, args.scene, verify=not args.no_verify)
        sheet, layout = contact_sheet(frames, title, args.tile_width, labels)
        out = write_image(args.output, sheet)
    except (ds.FormatError, ValueError) as e:
        print(f"dotsim show: error: {e}", file=sys.stderr)
        return 1
    print(f"wrote {out} ({sheet.shape[1]} x {sheet.shape[0]}): {len(frames)} frame(s) x "
          f"{len({c for _, c in layout.tiles})} pass(es)")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "show", help="draw a contact sheet of every pass of a scene or frame (PNG)",
        description="Draw a labelled contact sheet: one row per frame, one column per stored pass "
        "(IR, ambient, flood, depth, visibility and edge masks, projector column, disparity), "
        "colour bars in metres / pixels for the colour-mapped passes. PATH is a dataset directory "
        "(shows its first scene, or --scene N), a scene directory (shard_*/scene_*), or one frame EXR.")
    parser.add_argument("path", metavar="PATH", help="dataset dir, scene dir, or frame_K.exr")
    parser.add_argument("-o", "--output", default="contact_sheet.png",
                        help="image to write, .png or .jpg (default: contact_sheet.png)")
    parser.add_argument("--scene", type=int, default=None, metavar="N",
                        help="scene index to show when PATH is a dataset (default: the first)")
    parser.add_argument("--tile-width", type=int, default=320, metavar="PX",
                        help="width of each tile in pixels (default: 320)")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip sha256 verification of the files read (faster; see docs/FORMAT.md)")
    parser.set_defaults(func=run)
    return parser
