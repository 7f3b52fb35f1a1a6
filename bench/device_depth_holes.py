"""Where the simulated device leaves holes: the share of the pixels with ground truth that get no device
depth, split by cause, over the frames of a dataset, and a picture of one frame (docs/DEVICE_DEPTH.md).

    python -m bench.device_depth_holes DATASET [--scenes N] [--picture holes.png] [--scene 0] [--frame 0]
        [--jsonl rows.jsonl] [--set KEY=VALUE ...]

DATASET: stereo frames that store device_depth (`dotsim generate` with [device_depth] engine =
"stereo", e.g. --config bench/device_depth_tabletop.toml, the tabletop scenes of the docs). Each pixel
with ground truth (finite depth within the rig's max_depth) and no device depth is put in the first of
these causes that holds, each computed here from the ground truth and the stored IR, not from the
engine:
  band, border  the left band: columns left of the widest disparity the search reaches, and a border
                of one matching block at the image's four edges (answerable, from the scene's
                [device_depth] search range and block);
  occluded      the right camera does not see the point: a nearer surface to its right takes its
                place in the right view (right_occlusion: a scanline over the ground truth's disparity);
  depth edge    within half a block and a pixel of a depth edge of the ground truth (depth_edges);
  dotless       no dot the sensor sees in the block (the stored visibility mask: the projector's
                direct light above the sensor's noise; none in cast shadows nor on mirrors and glass)
                or a dark block (its 8-bit levels span fewer than --dark-levels);
  elsewhere     the rest: lit, dotted, seen by both cameras, away from edges.
Prints each frame's shares and the error of the depth it reports (median, share over 5 % off), then
the median and range over the frames. With --set the engine runs again on the stored IR pair with
those [device_depth] settings (the trade-offs of docs/DEVICE_DEPTH.md).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from dotsim.dataset import open_dataset, read_scene_meta
from dotsim.device_depth import DeviceDepthConfig, as_channel, search_range, stereo_depth
from dotsim.false_colour import colourise, legend_strip, titled
from dotsim.images import write_image
from dotsim.rig.geometry import Rig

CAUSES = ("band, border", "occluded", "depth edge", "dotless", "elsewhere")
KEYS = ("none",) + CAUSES + ("median error", "over 5 % off")
# Picture colours (BGR) of the causes, and of pixels with device depth / without ground truth.
CAUSE_COLOURS = {"band, border": (160, 160, 160), "occluded": (200, 60, 200), "depth edge": (0, 0, 230),
                 "dotless": (230, 120, 0), "elsewhere": (0, 220, 255)}
VALID_COLOUR, NO_TRUTH_COLOUR = (40, 40, 40), (0, 0, 0)
# Relative depth change between neighbouring pixels above which two pixels lie on different surfaces.
EDGE_STEP = 0.03
PANEL = (480, 270)  # each panel's size in the picture, px


def answerable(shape: tuple[int, int], low: int, count: int, block: int) -> np.ndarray:
    """Pixels (bool, shape) the device can answer for: its whole search, disparities low .. low + count
    - 1, inside the right image (u >= low + count - 1), and a block (`block` px, the engine's margin:
    docs/DEVICE_DEPTH.md) away from the image's four edges.

    >>> answerable((7, 12), 0, 5, 2).astype(int)[3]  # the left band: columns 0-3; 2 px at the right
    array([0, 0, 0, 0, 1, 1, 1, 1, 1, 1, 0, 0])
    >>> answerable((7, 12), 0, 5, 2).astype(int)[:, 6]
    array([0, 0, 1, 1, 1, 0, 0])
    """
    height, width = shape
    u, v = np.arange(width)[None, :], np.arange(height)[:, None]
    return ((u >= low + count - 1) & (u >= block) & (u < width - block)
            & (v >= block) & (v < height - block))


def right_occlusion(disparity: np.ndarray) -> np.ndarray:
    """Where the right camera cannot see a left pixel's point (bool (H, W)): the point of left column u
    lands at right column u - d(u); a point further right in the row that lands at or left of it is
    nearer (a larger disparity) and hides it. A pixel without disparity (nan) hides nothing.

    >>> d = np.array([[2.0, 2, 2, 2, 5, 5, 2, 2]])  # a wall (2 px), a box (5 px) on columns 4-5
    >>> right_occlusion(d).astype(int)  # the box lands on -1 .. 0: the wall's columns 1-3 behind it
    array([[0, 1, 1, 1, 0, 0, 0, 0]])
    """
    d = np.asarray(disparity, np.float64)
    lands = np.where(np.isfinite(d), np.arange(d.shape[1])[None, :] - d, np.inf)
    # the smallest landing column of the pixels to the right of each pixel
    after = np.minimum.accumulate(lands[:, ::-1], axis=1)[:, ::-1]
    after = np.concatenate([after[:, 1:], np.full((d.shape[0], 1), np.inf)], axis=1)
    return np.isfinite(d) & (after <= lands)


def depth_edges(depth: np.ndarray, radius: int) -> np.ndarray:
    """Pixels within `radius` (a square) of a depth edge: a neighbour (right or below) whose depth
    differs by more than EDGE_STEP of the nearer one, or has no depth (bool (H, W)).

    >>> z = np.ones((1, 8)); z[0, 4:] = 2.0
    >>> depth_edges(z, 1).astype(int)  # the step between columns 3 and 4, one pixel either side
    array([[0, 0, 1, 1, 1, 1, 0, 0]])
    """
    z = np.where(np.isfinite(depth), depth, np.inf)
    edge = np.zeros(z.shape, bool)
    for axis in (0, 1):
        a, b = (z[:-1], z[1:]) if axis == 0 else (z[:, :-1], z[:, 1:])
        with np.errstate(invalid="ignore"):
            jump = ~(np.abs(a - b) <= EDGE_STEP * np.minimum(a, b))
        if axis == 0:
            edge[:-1] |= jump
            edge[1:] |= jump
        else:
            edge[:, :-1] |= jump
            edge[:, 1:] |= jump
    kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
    return cv2.dilate(edge.astype(np.uint8), kernel) > 0


def dotless(visibility: np.ndarray, ir: np.ndarray, block: int, dark_levels: float) -> np.ndarray:
    """Blocks with nothing to match (bool (H, W)): no visible dot in the block around the pixel, or the
    left IR's 8-bit levels (full scale 255) in the block span fewer than `dark_levels`.

    >>> vis = np.zeros((5, 9), np.uint8); vis[2, 1] = vis[2, 7] = 1
    >>> ir = np.zeros((5, 9)); ir[2, 1], ir[2, 7] = 10 / 255, 2 / 255
    >>> dotless(vis, ir, 3, 4.0).astype(int)[2]  # no dot in columns 3-5; the dot at 7 only 2 levels
    array([0, 0, 0, 1, 1, 1, 1, 1, 1])
    """
    kernel = np.ones((block, block), np.uint8)
    no_dot = cv2.dilate((np.asarray(visibility) > 0).astype(np.uint8), kernel) == 0
    levels = np.clip(np.nan_to_num(np.asarray(ir, np.float32)) * 255, 0, 255)
    span = cv2.dilate(levels, kernel) - cv2.erode(levels, kernel)
    return no_dot | (span < dark_levels)


def hole_causes(device: np.ndarray, truth: np.ndarray, ir: np.ndarray, visibility: np.ndarray,
                fx_baseline: float, answered: np.ndarray, block: int, dark_levels: float) -> np.ndarray:
    """Each pixel's cause (int8 (H, W)): -2 no ground truth (nan), -1 device depth, else the index in
    CAUSES of the first cause that holds for a hole."""
    has_truth = np.isfinite(truth)
    disparity = np.where(has_truth, fx_baseline / np.where(has_truth, truth, 1.0), np.nan)
    tests = [~answered, right_occlusion(disparity),
             depth_edges(truth, block // 2 + 1), dotless(visibility, ir, block, dark_levels),
             np.ones(truth.shape, bool)]
    cause = np.full(truth.shape, -1, np.int8)
    hole = has_truth & ~np.isfinite(device)
    for index in range(len(CAUSES) - 1, -1, -1):
        cause[hole & tests[index]] = index
    cause[~has_truth] = -2
    return cause


def shares(cause: np.ndarray) -> dict:
    """Share of the pixels with ground truth without device depth, in all and per cause.

    >>> shares(np.array([-2, -1, -1, 0, 3]))
    {'none': 0.5, 'band, border': 0.25, 'occluded': 0.0, 'depth edge': 0.0, 'dotless': 0.25, 'elsewhere': 0.0}
    """
    with_truth = max(int((cause >= -1).sum()), 1)
    out = {"none": float((cause >= 0).sum() / with_truth)}
    out.update({name: float((cause == i).sum() / with_truth) for i, name in enumerate(CAUSES)})
    return out


def errors(device: np.ndarray, truth: np.ndarray) -> dict:
    """The relative error of the device's depth where it reports one and the truth has one: its median
    and the share of those pixels more than 5 % off (nan when there are none).

    >>> errors(np.array([1.0, 2.2, np.nan, 1.01]), np.array([1.0, 2.0, 1.0, np.nan]))
    {'median error': 0.05, 'over 5 % off': 0.5}
    """
    both = np.isfinite(device) & np.isfinite(truth)
    relative = np.abs(device[both] - truth[both]) / truth[both]
    if relative.size == 0:
        return {"median error": float("nan"), "over 5 % off": float("nan")}
    return {"median error": round(float(np.median(relative)), 6),
            "over 5 % off": float((relative > 0.05 + 1e-9).mean())}


def _setting(text: str) -> tuple[str, object]:
    """KEY=VALUE of --set, the value as an int, else a float, else the string."""
    key, equals, value = text.partition("=")
    if not equals or not key:
        raise ValueError(f"--set {text!r}: expected KEY=VALUE, e.g. score_threshold=0.5")
    for kind in (int, float):
        try:
            return key, kind(value)
        except ValueError:
            pass
    return key, value


def picture(frame: dict, truth: np.ndarray, cause: np.ndarray, row: dict) -> np.ndarray:
    """IR (left, sqrt) and ground truth above, device depth and its holes coloured by cause below, a
    legend (depth scale, what each colour means and its share) under them."""
    def panel(image: np.ndarray, title: str) -> np.ndarray:
        return titled(cv2.resize(image, PANEL, interpolation=cv2.INTER_NEAREST), title, PANEL[0])

    low, high = np.nanpercentile(truth, 1), np.nanpercentile(truth, 99)
    ir = np.clip(np.sqrt(np.nan_to_num(frame["ir"].astype(np.float32))) * 255, 0, 255).astype(np.uint8)
    holes = np.zeros(cause.shape + (3,), np.uint8)
    holes[cause == -1], holes[cause == -2] = VALID_COLOUR, NO_TRUTH_COLOUR
    for i, name in enumerate(CAUSES):
        holes[cause == i] = CAUSE_COLOURS[name]
    top = np.concatenate([panel(cv2.cvtColor(ir, cv2.COLOR_GRAY2BGR), "IR (left camera, sqrt)"),
                          panel(colourise(truth, low, high), "ground truth depth")], axis=1)
    bottom = np.concatenate([panel(colourise(frame["device_depth"], low, high),
                                   f"device depth: {row['none']:.0%} of the pixels none"),
                             panel(holes, "the holes by cause")], axis=1)
    swatches = ((VALID_COLOUR, "device depth reported"), (NO_TRUTH_COLOUR, "no ground truth; in depth: none"),
                *((CAUSE_COLOURS[name], f"hole: {name} ({row[name]:.1%} of the pixels)") for name in CAUSES))
    grid = np.concatenate([top, bottom], axis=0)
    return np.concatenate([grid, legend_strip(grid.shape[1], low, high, "m", swatches)], axis=0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--scenes", type=int, default=0, help="first N scenes (0: all)")
    parser.add_argument("--dark-levels", type=float, default=4.0,
                        help="8-bit level span below which a block counts as dark (default 4)")
    parser.add_argument("--picture", type=Path, default=None, help="write the picture of --scene/--frame")
    parser.add_argument("--scene", type=int, default=0)
    parser.add_argument("--frame", type=int, default=0)
    parser.add_argument("--jsonl", type=Path, default=None, help="write one row per frame")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a [device_depth] setting to run the engine with again on the stored IR pair "
                             "instead of reading the stored device_depth (repeatable; docs/CONFIG.md)")
    args = parser.parse_args(argv)
    try:
        changes = dict(_setting(text) for text in args.set)
        dataset = open_dataset(args.dataset)
    except (ValueError, OSError) as error:
        parser.exit(2, f"bench.device_depth_holes: {error}\n")
    count = len(dataset.scenes) if args.scenes <= 0 else min(args.scenes, len(dataset.scenes))
    rows = []
    for index in range(count):
        meta = read_scene_meta(dataset.scenes[index].path)
        rig = Rig.from_dict(meta["rig"])
        try:
            settings = DeviceDepthConfig.from_dict({**meta["config"]["device_depth"], **changes}, "--set")
        except ValueError as error:
            parser.exit(2, f"bench.device_depth_holes: {error}\n")
        if settings.engine != "stereo":
            raise SystemExit(f"{args.dataset}: scene {index}'s device_depth engine is {settings.engine!r}; "
                             f"this bench needs stereo frames")
        low, search = search_range(settings, meta["config"]["rig"]["scale"])
        fx_baseline = rig.camera.fx * rig.second_camera_translation[0]
        for number, frame in enumerate(dataset.read_scene(index).frames):
            truth = np.where(frame["depth"] <= rig.max_depth, frame["depth"], np.nan)
            if changes:
                frame = {**frame, "device_depth": as_channel(stereo_depth(
                    frame["ir"].astype(np.float32), frame["ir_right"].astype(np.float32), rig.camera.fx,
                    rig.second_camera_translation[0], settings, meta["config"]["rig"]["scale"]))}
            cause = hole_causes(frame["device_depth"], truth, frame["ir"], frame["visibility"], fx_baseline,
                                answerable(truth.shape, low, search, settings.block_size),
                                settings.block_size, args.dark_levels)
            row = {"scene": index, "frame": number, **shares(cause), **errors(frame["device_depth"], truth)}
            rows.append(row)
            print("scene {scene} frame {frame}: ".format(**row)
                  + ", ".join(f"{key} {row[key]:.2%}" for key in KEYS), flush=True)
            if args.picture is not None and (index, number) == (args.scene, args.frame):
                write_image(args.picture, picture(frame, truth, cause, row))
    if args.jsonl is not None:
        args.jsonl.write_text("".join(json.dumps(row) + "\n" for row in rows))
    print(f"{len(rows)} frames; median (lowest-highest):")
    for key in KEYS:
        values = np.array([row[key] for row in rows])
        print(f"  {key:14s} {np.median(values):6.2%} ({values.min():.2%}-{values.max():.2%})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
