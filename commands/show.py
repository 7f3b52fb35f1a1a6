"""`dotsim show`: a labelled contact sheet of every pass of every frame of a scene (PNG), an
overview of the IR of many scenes, and a frame's ground-truth point cloud (PLY).

Sheet: rows are frames, columns the stored passes (docs/FORMAT.md; as dotsim.channels declares how
each is shown), each column on its own scale, written above it: IR (and a stereo pair's right IR)
linear on the sensor's full scale, ambient and flood each as the square root
of value / its own 99th percentile (ambient is often 50x darker than flood, and radiance falls as
1 / r^2, so a linear scale shows near objects only), depth, projector column and disparity
colour-mapped (turbo) with a colour bar in their units under the grid (and a stereo pair's stereo
disparity), the visibility and edge masks (and a stereo pair's stereo visibility) white where set;
with labels, the instance and material labels a colour per value and the transparent_or_mirror mask;
with normals, the three normal components as one colour tile; with a colour camera ([render] rgb), its
image sRGB-encoded, white at its 99th percentile, fitted into the IR camera's tile (its own size and
aspect; the margin left grey).
Black in a colour-mapped tile means no value there (no hit / invalid).
numpy + OpenCV only.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from dotsim import dataset as ds
from dotsim.channels import CHANNEL, CHANNELS, NORMAL_CHANNELS
from dotsim.command_options import add_output
from dotsim.false_colour import (
    BACKGROUND,
    FONT,
    LINE,
    TEXT_SCALE,
    colour_image,
    colourise,
    label_colours,
    normal_colours,
    put_text,
    short_number,
)
from dotsim.images import write_image
from dotsim.option_types import integer
from dotsim.pointcloud import depth_points, grey_levels, write_ply
from dotsim.prediction_file import prediction_source
from dotsim.rig.geometry import Rig

# The sheet's columns and how each is drawn: the channels' one declaration (dotsim.channels).
COLUMNS = tuple(c.name for c in CHANNELS if c.display is not None)
GREY_CHANNELS = tuple(c.name for c in CHANNELS if c.display in ("linear", "radiance"))
COLOUR_MAPPED = tuple(c.name for c in CHANNELS if c.display == "colour")
# Under the columns of a `dotsim infer` output (dotsim.prediction_file): a network's estimate.
PREDICTED = "predicted (dotsim infer)"
FOOTNOTE = ("Each grey pass has its own scale, written above its column: IR linear on the sensor's full "
            "scale; ambient and flood (linear radiance) as the square root of value / white, white at "
            "their own 99th percentile. Masks: white = 1.")
GAP = 6  # between tiles, px
LABEL_WIDTH = 70  # left column with the frame labels, px
BAR_HEIGHT = 14
SUBTLE_COLOUR = (170, 200, 230)


@dataclass
class SheetLayout:
    """Where each tile of a contact sheet is: (frame, channel) -> (x, y, width, height)."""

    tiles: dict[tuple[int, str], tuple[int, int, int, int]]
    tile_size: tuple[int, int]  # (width, height)


def _grey(image: np.ndarray, scale: float, root: bool = False) -> np.ndarray:
    """Grey: value / scale clipped to [0, 1] (its square root with `root`) -> 0..255; non-finite ->
    black."""
    x = np.clip(np.where(np.isfinite(image), image.astype(np.float64) / scale, 0.0), 0, 1)
    return np.repeat(np.rint((np.sqrt(x) if root else x) * 255).astype(np.uint8)[..., None], 3, axis=2)


def _finite_range(arrays: list[np.ndarray]) -> tuple[float, float]:
    values = np.concatenate([a[np.isfinite(a)].ravel().astype(np.float64) for a in arrays])
    if values.size == 0:
        return 0.0, 1.0
    return float(values.min()), float(values.max())


def full_scale(image: np.ndarray) -> float:
    """The value that means full scale for an IR image: 1.0 for floats (fraction of full scale),
    the dtype's maximum for integer codes."""
    return float(np.iinfo(image.dtype).max) if np.issubdtype(image.dtype, np.integer) else 1.0


def _grey_scale(frames: list[dict], name: str) -> float:
    """Display scale (the value shown white) of a grey pass: IR its full scale; ambient and flood
    each its own 99th percentile over the frames (its maximum where that is 0), so a dark pass is
    not shown black; 0 for a pass that is 0 everywhere."""
    if CHANNEL[name].display == "linear":
        return full_scale(frames[0][name])
    values = np.concatenate([f[name][np.isfinite(f[name])].ravel() for f in frames]).astype(np.float64)
    if values.size == 0:
        return 0.0
    scale = float(np.percentile(values, 99))
    return scale if scale > 0 else float(max(values.max(), 0.0))


def grey_for_display(image: np.ndarray, name: str) -> np.ndarray:
    """(H, W) uint8 of one grey pass as the sheet shows it, scaled by this image alone: IR linear on
    full scale, ambient and flood as the square root of value over their own 99th percentile."""
    scale = _grey_scale([{name: image}], name)
    return _grey(image, scale or 1.0, root=CHANNEL[name].display == "radiance")[..., 0]


def scale_caption(name: str, scale: float) -> str:
    """The scale written above a grey column: the value its white stands for."""
    if CHANNEL[name].display == "linear":
        return "linear, white = full scale"
    if scale == 0:
        return "0 everywhere (no light)"
    return f"sqrt, white = {short_number(scale)}"


def _wrap(text: str, width: int) -> list[str]:
    """Words of text in lines at most `width` px wide at TEXT_SCALE."""
    lines = [""]
    for word in text.split():
        candidate = f"{lines[-1]} {word}".strip()
        if lines[-1] and cv2.getTextSize(candidate, FONT, TEXT_SCALE, 1)[0][0] > width:
            lines.append(word)
        else:
            lines[-1] = candidate
    return lines


def contact_sheet(frames: list[dict[str, np.ndarray]], title: str, tile_width: int = 320,
                  frame_labels: list[str] | None = None,
                  meanings: dict[str, str] | None = None) -> tuple[np.ndarray, SheetLayout]:
    """Draw the sheet (BGR uint8) for frames (channel -> (H, W) array, as read_frame returns).

    Columns follow COLUMNS, keeping the channels the frames have, each under its title and its
    meaning (its declaration's in dotsim.channels, or `meanings`' for the channels it names). Returns
    the image and where each tile is, so callers (and tests) can find a pass in it.
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
    scales = {c: _grey_scale(frames, c) for c in channels if c in GREY_CHANNELS}
    labels = frame_labels or [f"frame {k}" for k in range(len(frames))]
    meanings = {**{c.name: c.meaning for c in CHANNELS}, **(meanings or {})}

    top = 4 * LINE + GAP  # title line, column title, meaning, scale
    grid_w = len(channels) * (tile_w + GAP)
    sheet_w = LABEL_WIDTH + grid_w + GAP
    footnote = _wrap(FOOTNOTE, sheet_w - 2 * GAP)
    legend_h = (LINE + BAR_HEIGHT + LINE) * len(ranges) + (len(footnote) + 1) * LINE + GAP
    sheet_h = top + len(frames) * (tile_h + GAP) + legend_h
    sheet = np.full((sheet_h, sheet_w, 3), BACKGROUND, np.uint8)
    put_text(sheet, title, GAP, LINE - 4)

    tiles = {}
    for j, name in enumerate(channels):
        x = LABEL_WIDTH + j * (tile_w + GAP)
        put_text(sheet, CHANNEL[name].title, x, 2 * LINE - 4, width=tile_w)
        put_text(sheet, meanings[name], x, 3 * LINE - 4, SUBTLE_COLOUR, width=tile_w)
        if name in scales:
            caption = scale_caption(name, scales[name])
        elif name in ranges:
            low, high = ranges[name]
            caption = f"{short_number(low)}..{short_number(high)} {CHANNEL[name].unit}"
        elif CHANNEL[name].display == "labels":
            caption = "a colour per label, black = 0"
        elif CHANNEL[name].display == "normal":
            caption = "RGB = (xyz + 1) / 2"
        elif CHANNEL[name].display == "colour image":
            caption = f"sRGB, white = 99th pct, {frames[0][name].shape[1]} x {frames[0][name].shape[0]}"
        else:
            caption = "mask 0 / 1"
        put_text(sheet, caption, x, 4 * LINE - 4, SUBTLE_COLOUR, width=tile_w)
        for k, frame in enumerate(frames):
            y = top + k * (tile_h + GAP)
            image = frame[name]
            if name in COLOUR_MAPPED:
                tile = colourise(image, *ranges[name])
            elif CHANNEL[name].display == "mask":
                tile = _grey(image, 1.0)
            elif CHANNEL[name].display == "labels":
                tile = label_colours(image)
            elif CHANNEL[name].display == "normal":
                tile = normal_colours(*(frame[axis] for axis in NORMAL_CHANNELS))
            elif CHANNEL[name].display == "colour image":  # its own camera's size: fitted, not stretched
                sheet[y:y + tile_h, x:x + tile_w] = _fitted(colour_image(image), tile_w, tile_h)
                tiles[(k, name)] = (x, y, tile_w, tile_h)
                continue
            elif CHANNEL[name].display == "linear":
                tile = _grey(image, scales[name])
            else:  # radiance falls off as 1 / r^2: a square root shows far walls beside near objects
                tile = _grey(image, scales[name] or 1.0, root=True)
            # labels and normals are not averaged across a tile's pixels (no colour of its own)
            exact = CHANNEL[name].display in ("labels", "normal")
            tile = cv2.resize(tile, (tile_w, tile_h),
                              interpolation=cv2.INTER_NEAREST if exact else cv2.INTER_AREA)
            sheet[y:y + tile_h, x:x + tile_w] = tile
            tiles[(k, name)] = (x, y, tile_w, tile_h)
    for k, label in enumerate(labels):
        put_text(sheet, label, GAP, top + k * (tile_h + GAP) + tile_h // 2)

    y = top + len(frames) * (tile_h + GAP) + LINE
    for name, (low, high) in ranges.items():
        put_text(sheet, f"{CHANNEL[name].title} ({CHANNEL[name].unit}), black = none", LABEL_WIDTH, y)
        bar_w = min(grid_w - GAP, 512)
        ramp = np.linspace(low, high, bar_w)[None, :].repeat(BAR_HEIGHT, axis=0)
        sheet[y + 4:y + 4 + BAR_HEIGHT, LABEL_WIDTH:LABEL_WIDTH + bar_w] = colourise(ramp, low, high)
        for frac in (0.0, 0.25, 0.5, 0.75, 1.0):
            tx = LABEL_WIDTH + int(frac * (bar_w - 1))
            put_text(sheet, short_number(low + frac * (high - low)), min(tx, sheet_w - 50),
                     y + BAR_HEIGHT + LINE)
        y += LINE + BAR_HEIGHT + LINE
    for line in footnote:
        put_text(sheet, line, GAP, y)
        y += LINE
    return sheet, SheetLayout(tiles=tiles, tile_size=(tile_w, tile_h))


def _fitted(image: np.ndarray, width: int, height: int) -> np.ndarray:
    """`image` (BGR) scaled to fit a width x height tile, its aspect kept, centred on the background."""
    scale = min(width / image.shape[1], height / image.shape[0])
    w, h = max(1, round(image.shape[1] * scale)), max(1, round(image.shape[0] * scale))
    tile = np.full((height, width, 3), BACKGROUND, np.uint8)
    y, x = (height - h) // 2, (width - w) // 2
    tile[y:y + h, x:x + w] = cv2.resize(image, (w, h), interpolation=cv2.INTER_AREA)
    return tile


def scene_path_of(path: str | Path, scene_index: int | None = None) -> Path:
    """The scene directory PATH names: PATH itself when it holds scene.json, else scene
    `scene_index` (default the first) of the dataset PATH; FormatError naming what is there."""
    path = Path(path)
    if (path / ds.SCENE_FILE).is_file():
        return path
    if not path.is_dir():
        raise ds.FormatError(f"{path}: no such file or directory")
    scenes = ds.complete_scenes(path)
    if not scenes:
        raise ds.FormatError(f"{path}: no complete scene found (neither a scene directory with "
                             f"{ds.SCENE_FILE}, nor a dataset with shard_*/scene_* inside)")
    if scene_index is None:
        return scenes[0][1]
    found = dict(scenes)
    if scene_index not in found:
        raise ds.FormatError(f"{path}: no scene {scene_index}; it has scenes "
                             f"{scenes[0][0]}..{scenes[-1][0]} ({len(scenes)} in all)")
    return found[scene_index]


def load_for_sheet(path: str | Path, scene_index: int | None = None,
                   verify: bool = True) -> tuple[list[dict], str, list[str], dict[str, str]]:
    """Frames, a title, row labels and the meanings of the columns that differ from their declared ones, for
    PATH: a dataset dir (scene `scene_index`, default the first), a scene dir, one frame EXR, or one
    output EXR of `dotsim infer` (its disparity and depth labelled as predictions)."""
    path = Path(path)
    if path.is_file():
        frame = ds.read_frame(path, verify=verify)
        h, w = next(iter(frame.values())).shape
        source = prediction_source(path)
        if source is None:
            return [frame], f"{path}  ({w} x {h})", [path.stem], {}
        names = {key: Path(str(source.get(key, "?"))).name for key in ("checkpoint", "input")}
        title = (f"{path.name}  ({w} x {h}): PREDICTED by {names['checkpoint']} from {names['input']} "
                 f"(dotsim infer), not ground truth")
        return [frame], title, [path.stem], {name: PREDICTED for name in frame}
    scene_path = scene_path_of(path, scene_index)
    scene = ds.read_scene(scene_path, verify=verify)
    meta = scene.meta
    h, w = ds.camera_size(meta)
    title = (f"{scene_path}  scene {meta['scene_index']} ({meta['split']}), rig "
             f"{meta['rig'].get('name', '?')}, {w} x {h}, format {meta['format_version']}")
    return scene.frames, title, [f"frame {k}" for k in range(len(scene.frames))], {}


def overview_sheet(tiles: list[tuple[str, np.ndarray]], title: str, tile_width: int = 240,
                   columns: int = 6) -> tuple[np.ndarray, dict[str, tuple[int, int, int, int]]]:
    """A grid of IR images (label, (H, W) IR), each on the sensor's full scale, labelled under it.

    Returns the sheet (BGR uint8) and label -> (x, y, width, height) of its tile."""
    if not tiles:
        raise ValueError("an overview needs at least one image")
    if int(tile_width) < 16 or int(columns) < 1:
        raise ValueError(f"tile width must be at least 16 px and columns at least 1, got {tile_width}, "
                         f"{columns}")
    h, w = tiles[0][1].shape
    tile_w = int(tile_width)
    tile_h = max(1, round(tile_w * h / w))
    columns = min(int(columns), len(tiles))
    rows = -(-len(tiles) // columns)
    top = 2 * LINE + GAP
    cell_h = tile_h + LINE + GAP
    sheet = np.full((top + rows * cell_h + GAP, GAP + columns * (tile_w + GAP), 3), BACKGROUND, np.uint8)
    put_text(sheet, title, GAP, LINE - 4)
    put_text(sheet, "IR (projector on, as the sensor sees it); white = the sensor's full scale", GAP,
          2 * LINE - 4, SUBTLE_COLOUR)
    where = {}
    for n, (label, ir) in enumerate(tiles):
        x = GAP + (n % columns) * (tile_w + GAP)
        y = top + (n // columns) * cell_h
        tile = cv2.resize(_grey(ir, full_scale(ir)), (tile_w, tile_h), interpolation=cv2.INTER_AREA)
        sheet[y:y + tile_h, x:x + tile_w] = tile
        put_text(sheet, label, x, y + tile_h + LINE - 4)
        where[label] = (x, y, tile_w, tile_h)
    return sheet, where


def load_overview(path: str | Path, frame: int = 0, max_scenes: int = 24,
                  verify: bool = True) -> tuple[list[tuple[str, np.ndarray]], str]:
    """(label, IR of frame `frame`) of the first `max_scenes` complete scenes of dataset PATH, and a
    title naming how many of how many are shown."""
    path = Path(path)
    scenes = ds.complete_scenes(path)
    if not scenes:
        raise ds.FormatError(f"{path}: no complete scene found (an overview needs a dataset directory "
                             f"with shard_*/scene_* inside)")
    if max_scenes < 1:
        raise ValueError(f"--scenes {max_scenes}: show at least 1 scene")
    tiles = []
    for index, scene_path in scenes[:max_scenes]:
        meta = ds.read_scene_meta(scene_path, verify=verify)
        if not 0 <= frame < len(meta["frames"]):
            raise ds.FormatError(f"{scene_path}: no frame {frame}; it has {len(meta['frames'])}")
        ir = ds.read_frame(scene_path / ds.frame_name(frame), verify=verify, channels=("ir",), meta=meta)
        tiles.append((f"scene {index} ({meta['split']})", ir["ir"]))
    title = f"{path}: IR of frame {frame} of {len(tiles)} of {len(scenes)} scene(s)"
    return tiles, title


def write_ground_truth_ply(path: str | Path, out: str | Path, scene_index: int | None = None,
                           frame: int = 0, verify: bool = True) -> int:
    """Write the ground-truth cloud of frame `frame` of the scene PATH names (scene_path_of) to
    `out` (PLY, camera frame, IR grey); returns the number of points."""
    scene_path = scene_path_of(path, scene_index)
    meta = ds.read_scene_meta(scene_path, verify=verify)
    if not 0 <= frame < len(meta["frames"]):
        raise ds.FormatError(f"{scene_path}: no frame {frame}; it has {len(meta['frames'])}")
    f = ds.read_frame(scene_path / ds.frame_name(frame), verify=verify, channels=("ir", "depth"), meta=meta)
    rig = Rig.from_dict(meta["rig"])
    points, grey = depth_points(f["depth"], rig.camera, grey_levels(f["ir"]))
    write_ply(out, points, grey)
    return len(points)


def run(args: argparse.Namespace) -> int:
    verify = not args.no_verify
    if args.ply:
        if Path(args.path).is_file():
            raise ds.FormatError(f"{args.path}: --ply needs the scene's rig: give a scene or dataset "
                                 f"directory")
        n = write_ground_truth_ply(args.path, args.ply, args.scene, args.frame, verify)
        print(f"wrote {args.ply}: {n} ground-truth points of frame {args.frame} (metres, camera frame)")
        return 0
    if args.overview:
        tiles, title = load_overview(args.path, args.frame, args.scenes, verify)
        sheet, _ = overview_sheet(tiles, title, args.tile_width)
        out = write_image(args.output, sheet)
        print(f"wrote {out} ({sheet.shape[1]} x {sheet.shape[0]}): IR of {len(tiles)} scene(s)")
        return 0
    frames, title, labels, meanings = load_for_sheet(args.path, args.scene, verify=verify)
    sheet, layout = contact_sheet(frames, title, args.tile_width, labels, meanings)
    out = write_image(args.output, sheet)
    print(f"wrote {out} ({sheet.shape[1]} x {sheet.shape[0]}): {len(frames)} frame(s) x "
          f"{len({c for _, c in layout.tiles})} pass(es)")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "show", help="contact sheet of a scene's passes, an IR overview of many scenes, or a GT point cloud",
        description="Draw a labelled contact sheet: one row per frame, one column per stored pass "
        "(IR, ambient, flood, depth, visibility and edge masks, projector column, disparity; of a stereo "
        "pair also the right IR, the stereo visibility mask and the stereo disparity), each on "
        "its own scale written above it, colour bars in metres / pixels for the colour-mapped passes. "
        "PATH is a dataset directory (shows its first scene, or --scene N), a scene directory "
        "(shard_*/scene_*), one frame EXR, or an output EXR of `dotsim infer` (its columns labelled as "
        "predictions). --overview draws the IR of many scenes of a dataset in "
        "one grid instead; --ply writes a frame's ground-truth point cloud instead.")
    parser.add_argument("path", metavar="PATH", help="dataset dir, scene dir, or frame_K.exr")
    add_output(parser, "image to write, .png or .jpg (default: contact_sheet.png)", metavar="FILE",
               required=False, old=("--output",), dest="output", default="contact_sheet.png")
    parser.add_argument("--scene", type=integer(0), default=None, metavar="N",
                        help="scene index to show when PATH is a dataset (default: the first)")
    parser.add_argument("--frame", type=integer(0), default=0, metavar="K",
                        help="the frame --overview and --ply use (default: 0)")
    parser.add_argument("--overview", action="store_true",
                        help="a grid of the IR of the first --scenes scenes of the dataset PATH")
    parser.add_argument("--scenes", type=integer(1), default=24, metavar="N",
                        help="how many scenes --overview shows (default: 24)")
    parser.add_argument("--ply", default=None, metavar="OUT.ply",
                        help="write the ground-truth point cloud of --frame (metres, OpenCV camera frame, "
                        "IR grey colours; through trimesh) instead of a sheet")
    parser.add_argument("--tile-width", type=integer(16), default=320, metavar="PX",
                        help="width of each tile in pixels (default: 320)")
    parser.add_argument("--no-verify", action="store_true",
                        help="skip sha256 verification of the files read (faster; see docs/FORMAT.md)")
    parser.set_defaults(func=run, errors={ds.FormatError: 1, ValueError: 1})
    return parser
