"""One scorer for every disparity method: `dotsim eval`, training's validation and SGBM's preprocessing
choice all count with it.

A method is an object with a `name`, the frame `channels` it reads beyond the IR, `predict(frame)` (its
full-resolution disparity in camera px, nan where it gives none) and `reachable(gt, depth)` (the pixels
whose GT disparity lies inside the range the method can represent: its feasible range): the network
(NetworkMethod), SGBM against the pattern (SgbmMethod), SGBM between a stereo pair's IR images
(StereoSgbmMethod), the depth camera's own depth stored beside the frames (DeviceDepthMethod) and the GT
taken at a stride-2 network's output pixels (HalfResolutionFloor: what output resolution alone costs). The
Scorer runs methods over frames and counts, per method and pixel class ("all", each GT depth range, on /
off the edge mask, slanted off it, solvable or not: dotsim/solvable.py), the valid pixels, those outside
the method's range and the outliers at each threshold (trainer/metrics.py); `rows()` turns the counts
into table rows. `error_strip` draws the one error image both eval and validation show.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from dotsim.false_colour import titled, with_legend
from dotsim.frame_source import FrameRef
from dotsim.rig.geometry import Rig, depth_to_projector_column, disparity_to_depth
from dotsim.solvable import solvable_pixels
from trainer.checkpoint import predict_disparity
from trainer.device_depth_row import DEVICE_LABEL, DEVICE_METHOD, device_disparity
from trainer.metrics import (
    THRESHOLDS,
    joint_outliers,
    outlier_counts,
    outlier_rate,
    outside_range,
    valid_pixels,
)
from trainer.sgbm import sgbm_disparity, stereo_sgbm_disparity
from trainer.upsampling import full_resolution_disparity, pattern_reference

DEPTH_BINS = (0.0, 1.0, 2.0, 4.0, 8.0, 20.0)  # metres; cut at the rig's max_depth (depth_ranges)
# depth follows from disparity: exports may hold no depth
SCORED_CHANNELS = ("ir", "visibility", "disparity", "edge")
CLASSES = ("edge", "off edge", "slanted", "solvable", "not solvable")  # beside the depth ranges
SLANT = 0.05  # px of disparity per px: the pattern stretched or sheared by 5 % or more


def depth_ranges(depth_bins, max_depth: float) -> tuple[float, ...]:
    """The bin edges below a rig's max_depth, closed by it: no row for depths the rig never holds.

    >>> depth_ranges(DEPTH_BINS, 6.0), depth_ranges(DEPTH_BINS, 20.0)
    ((0.0, 1.0, 2.0, 4.0, 6.0), (0.0, 1.0, 2.0, 4.0, 8.0, 20.0))
    """
    return tuple(b for b in depth_bins if b < max_depth) + (max_depth,)


def disparity_slopes(disparity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(|change along the row|, |change down the column|) of a disparity map, px per px, by central
    differences (one-sided at the borders); nan beside a pixel without disparity.

    >>> along, down = disparity_slopes(np.array([[0.0, 1.0, 2.0], [0.5, 1.5, 2.5]]))
    >>> along[0].tolist(), down[0].tolist()
    ([1.0, 1.0, 1.0], [0.5, 0.5, 0.5])
    """
    down, along = np.gradient(disparity.astype(np.float64))
    return np.abs(along), np.abs(down)


def slanted_pixels(disparity: np.ndarray) -> np.ndarray:
    """Pixels whose GT disparity changes by more than SLANT px per px along the row or down the column
    (disparity_slopes; a pixel beside one without disparity has no slope): surfaces slanted in depth,
    whose pattern is stretched along the rows or sheared against the pattern a plane facing the camera
    shows, where learned depth sensors fail first.

    >>> ramp = np.tile(np.arange(5.0), (3, 1))
    >>> bool(slanted_pixels(0.1 * ramp).all()), bool(slanted_pixels(0.02 * ramp).any())
    (True, False)
    """
    with np.errstate(invalid="ignore"):
        return np.maximum(*disparity_slopes(disparity)) > SLANT


def pixel_classes(valid: np.ndarray, depth: np.ndarray, edge: np.ndarray | None = None,
                  solvable: np.ndarray | None = None, depth_bins=DEPTH_BINS,
                  disparity: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The valid pixels by class: "all", each GT depth range "a-b" (m), and where given on / off the
    edge mask, slanted off the edge mask (slanted_pixels of the GT disparity) and solvable or not
    (dotsim/solvable.py)."""
    with np.errstate(invalid="ignore"):
        classes = {"all": valid} | {f"{a:g}-{b:g}": valid & (depth >= a) & (depth < b)
                                    for a, b in zip(depth_bins[:-1], depth_bins[1:], strict=True)}
    if edge is not None:
        classes |= {"edge": valid & (edge > 0), "off edge": valid & ~(edge > 0)}
        if disparity is not None:
            classes["slanted"] = classes["off edge"] & slanted_pixels(disparity)
    if solvable is not None:
        classes |= {"solvable": valid & solvable, "not solvable": valid & ~solvable}
    return classes


@dataclass(frozen=True)
class NetworkMethod:
    """The trained network: any column inside the projector image, no nearer than [model] min_depth."""

    model: object
    rig: Rig
    device: str = "cpu"
    precision: str = "float32"
    reference: np.ndarray | None = field(default=None, repr=False)  # predict_disparity's
    name: str = "network"
    channels: tuple[str, ...] = ()

    def predict(self, frame: dict) -> np.ndarray:
        return predict_disparity(self.model, self.rig, frame["ir"], self.device, self.precision,
                                 self.reference)[0]

    def reachable(self, gt: np.ndarray, depth: np.ndarray) -> np.ndarray:
        column = depth_to_projector_column(depth, self.rig, normalised=True)
        with np.errstate(invalid="ignore"):
            return (column >= 0) & (column <= 1) & (depth >= self.model.cfg.min_depth)


@dataclass(frozen=True)
class SgbmMethod:
    """StereoSGBM of the IR against the pattern as seen from infinity: disparities 0 .. n - 1."""

    reference: np.ndarray = field(repr=False)
    num_disparities: int
    preprocessing: str = "plain"
    channels: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return f"sgbm-{self.preprocessing}"

    def predict(self, frame: dict) -> np.ndarray:
        return sgbm_disparity(frame["ir"], self.reference, self.num_disparities,
                              preprocessing=self.preprocessing)

    def reachable(self, gt: np.ndarray, depth: np.ndarray) -> np.ndarray:
        return gt <= self.num_disparities - 1


@dataclass(frozen=True)
class StereoSgbmMethod:
    """StereoSGBM between a stereo pair's left and right IR (GigaDepth's captured-data baseline). Its
    left-right disparity d_s = fx B_s / z is scored as the depth it gives, in the projector disparity's
    pixels: d_s * to_projector (B / B_s), so every method judges the same depth error alike."""

    num_disparities: int
    to_projector: float
    name: str = "sgbm-stereo"
    channels: tuple[str, ...] = ("ir_right",)

    def predict(self, frame: dict) -> np.ndarray:
        right = frame["ir_right"].astype(np.float32)
        return stereo_sgbm_disparity(frame["ir"], right, self.num_disparities) * self.to_projector

    def reachable(self, gt: np.ndarray, depth: np.ndarray) -> np.ndarray:
        return gt / self.to_projector <= self.num_disparities - 1


@dataclass(frozen=True)
class DeviceDepthMethod:
    """The depth camera's own depth, the frames' device_depth channel (a recording's, or the simulated
    device's: docs/DEVICE_DEPTH.md), as the projector disparity fx b / z of its depth; a pixel without a
    reading (NaN) is an outlier. It has no range of its own to fall outside: every pixel is reachable."""

    rig: Rig
    name: str = DEVICE_METHOD
    label: str = DEVICE_LABEL
    channels: tuple[str, ...] = ("device_depth",)

    def predict(self, frame: dict) -> np.ndarray:
        return device_disparity(frame, self.rig)

    def reachable(self, gt: np.ndarray, depth: np.ndarray) -> np.ndarray:
        return np.ones(gt.shape, bool)


@dataclass(frozen=True)
class HalfResolutionFloor:
    """What a perfect stride-2 network would still get wrong: the GT disparity itself taken at the output
    pixels (2i, 2j) and brought to full resolution as the network's output is (full_resolution_disparity,
    guided by `reference` as NetworkMethod's). Its outliers lie on depth edges, where a full-resolution
    pixel near samples on two surfaces takes the wrong one: the share of a network's errors its output
    resolution alone accounts for. The step is set for a network's samples, which are unsure near an
    edge: perfect samples lose a little to it (trainer.upsampling's MATCH_JUMP_PX)."""

    reference: np.ndarray | None = field(default=None, repr=False)
    name: str = "half-res floor"
    channels: tuple[str, ...] = ()

    def predict(self, frame: dict) -> np.ndarray:
        gt = frame["disparity"]
        return full_resolution_disparity(gt[0::2, 0::2], *gt.shape, frame["ir"], self.reference)

    def reachable(self, gt: np.ndarray, depth: np.ndarray) -> np.ndarray:
        return np.ones(gt.shape, bool)


class Scorer:
    """Counts of `methods` over frames, per pixel class: [valid pixels, outside the method's range,
    outliers at each threshold]. `classes`: keep only these classes (None: all); `feasible`: (low, high)
    disparities, counting each method's estimates outside them; `joint`: two method names whose outliers
    are compared pixel by pixel ("all" and "solvable" classes)."""

    def __init__(self, methods, rig: Rig, pattern: np.ndarray, depth_bins=(), classes=None,
                 feasible: tuple[float, float] | None = None, joint: tuple[str, str] | None = None,
                 thresholds=THRESHOLDS):
        self.methods, self.rig, self.pattern, self.depth_bins = list(methods), rig, pattern, depth_bins
        self.keep, self.feasible, self.joint_of, self.thresholds = classes, feasible, joint, thresholds
        self.channels = SCORED_CHANNELS + tuple(c for m in self.methods for c in m.channels)
        self.counts: dict[tuple[str, str], np.ndarray] = {}
        self.joint: dict[tuple[str, float], np.ndarray] = {}
        self.infeasible = dict.fromkeys((m.name for m in self.methods), 0)

    def prepare(self, ref: FrameRef) -> tuple[dict, dict[str, np.ndarray]]:
        """(the frame's channels the methods need, IR as float32; its pixel classes)."""
        frame = ref.read(self.channels)
        frame = {**frame, "ir": frame["ir"].astype(np.float32)}
        gt = frame["disparity"].astype(np.float64)
        valid = valid_pixels(frame["visibility"], frame["disparity"])
        depth = disparity_to_depth(gt, self.rig)
        solved = None
        if self.keep is None or {"solvable", "not solvable"} & set(self.keep):
            solved = solvable_pixels(frame["ir"], depth, self.rig, self.pattern, ref.scene_meta())
        disparity = gt if self.keep is None or "slanted" in self.keep else None  # for the slopes
        classes = pixel_classes(valid, depth, frame.get("edge"), solved, self.depth_bins, disparity)
        return frame, {k: v for k, v in classes.items() if self.keep is None or k in self.keep}

    def add(self, ref: FrameRef) -> tuple[dict, dict[str, np.ndarray]]:
        """Score one frame with every method; returns (the frame, {method name: prediction})."""
        frame, classes = self.prepare(ref)
        return frame, self.score(frame, classes)

    def score(self, frame: dict, classes: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        """Score a prepared frame with every method; returns {method name: prediction}."""
        gt = frame["disparity"].astype(np.float64)
        depth = disparity_to_depth(gt, self.rig)
        preds = {m.name: m.predict(frame) for m in self.methods}
        for m in self.methods:
            reachable = m.reachable(gt, depth)
            if self.feasible is not None:
                self.infeasible[m.name] += outside_range(preds[m.name], *self.feasible, classes["all"])
            for name, selected in classes.items():
                pixels, outliers = outlier_counts(preds[m.name], gt, selected, self.thresholds)
                count = np.array([pixels, int((selected & ~reachable).sum()), *outliers])
                self.counts[(m.name, name)] = self.counts.get((m.name, name), 0) + count
        for name in ("all", "solvable") if self.joint_of else ():
            for t in self.thresholds if name in classes else ():
                both = joint_outliers(preds[self.joint_of[0]], preds[self.joint_of[1]], gt, classes[name], t)
                self.joint[(name, t)] = self.joint.get((name, t), 0) + np.array(both)
        return preds

    def rows(self, chosen: str | None = None) -> list[dict]:
        """One row per (method, class): method, range (the class), pixels, outside, with `chosen` whether
        the method is that one, o(t) per threshold."""
        rows = []
        for (method, name), c in self.counts.items():
            row = {"method": method, "range": name, "pixels": int(c[0]), "outside": int(c[1])}
            row |= {} if chosen is None else {"chosen": method == chosen}
            row |= {f"o({t:g})": outlier_rate(int(c[2 + k]), int(c[0]))
                    for k, t in enumerate(self.thresholds)}
            rows.append(row)
        return rows


# Colours of the error images (BGR) and what they mean, for the images and their legends.
OUTLIER_COLOUR = (0, 0, 0)
NO_GT_COLOUR = (128, 128, 128)
ERROR_SWATCHES = ((OUTLIER_COLOUR, "black: error > 5 px, or no estimate (an outlier)"),
                  (NO_GT_COLOUR, "grey: no ground truth (pattern not visible), not scored"))
# The narrowest panel of an error strip (IR | network | SGBM): smaller frames are scaled up by a whole
# factor (dotsim.false_colour.titled), so that the title over each panel is readable.
PANEL_WIDTH = 240


def error_image(err: np.ndarray, valid: np.ndarray, max_px: float = 5.0) -> np.ndarray:
    """BGR uint8: |error| 0..max_px on the turbo colour map, outliers (> max_px or no estimate)
    black, pixels without ground truth mid grey (as GigaDepth's figures)."""
    err = np.abs(err)
    scaled = np.clip(np.nan_to_num(err, nan=0.0) / max_px * 255, 0, 255).astype(np.uint8)
    img = cv2.applyColorMap(scaled, cv2.COLORMAP_TURBO)
    img[~(err <= max_px)] = OUTLIER_COLOUR
    img[~valid] = NO_GT_COLOUR
    return img


def grey(ir: np.ndarray) -> np.ndarray:
    """IR as uint8 grey, its 99.5th percentile white."""
    scale = max(float(np.percentile(ir, 99.5)), 1e-12)
    return np.clip(ir / scale * 255, 0, 255).astype(np.uint8)


def error_strip(frame: dict, preds: dict[str, np.ndarray]) -> np.ndarray:
    """BGR uint8: the IR, then each method's |error| (error_image), titled, with a legend under them."""
    valid = valid_pixels(frame["visibility"], frame["disparity"])
    gt = frame["disparity"].astype(np.float64)
    panels = [titled(cv2.cvtColor(grey(frame["ir"]), cv2.COLOR_GRAY2BGR), "IR", PANEL_WIDTH)] + [
        titled(error_image(pred - gt, valid), f"{name} |err|", PANEL_WIDTH) for name, pred in preds.items()]
    sep = np.full((panels[0].shape[0], 2, 3), 255, np.uint8)
    strip = np.concatenate([p for panel in panels for p in (panel, sep)][:-1], axis=1)
    return with_legend(strip, 0.0, 5.0, "px |disparity error|", ERROR_SWATCHES)


class Validation:
    """A few held-out frames that training scores every [train].val_every steps with the Scorer: the
    network's o(t) over their valid pixels and over the solvable ones (dotsim/solvable.py, where the
    frames record their sensor), and the first frame's error_strip."""

    def __init__(self, frames: list[FrameRef], rig: Rig, pattern: np.ndarray):
        self.rig, self.pattern = rig, pattern
        self.reference = pattern_reference(pattern, rig)
        self.frames = [self.scorer(None).prepare(ref) for ref in frames]  # read once, at the start

    def scorer(self, method) -> Scorer:
        return Scorer([method] if method else [], self.rig, self.pattern, classes=("all", "solvable"))

    def __call__(self, model, device: str) -> tuple[dict[str, float], np.ndarray]:
        """({"all o(0.5)": rate, ...}, the first frame's error strip as RGB uint8)."""
        scorer = self.scorer(NetworkMethod(model, self.rig, device, reference=self.reference))
        preds = [scorer.score(frame, classes) for frame, classes in self.frames]
        image = error_strip(self.frames[0][0], preds[0])[..., ::-1]
        model.train()
        return {f"{r['range']} o({t:g})": r[f"o({t:g})"] for r in scorer.rows() for t in THRESHOLDS}, image
