"""Post-render stage (pure numpy): the Blender stage's raw passes of one frame -> the stored channels.

Raw passes (generator/blender SceneRenderer.render, float32 (H, W), linear radiance):
  projector  what the dot projector adds; flood  what the uniform flood rectangle adds;
  ambient    world + extra lights (projector off); depth  planar metres, inf where nothing is hit;
  projector_direct, flood_direct  the projector's and the flood's direct light alone (included in
  projector and flood);
  and the same of the rig's second camera, named with its suffix (projector_right, ...), when the
  spec renders the stereo pair (SceneSpec.cameras).
With the spec's ambient_ratio ([lighting] ambient_ratio) the ambient passes are first scaled so that
the ambient light over the projector's, averaged where the projector reaches directly, is that ratio
(ambient_scale; the right camera's by the same factor: one room).
Stored channels (dotsim.channels, the channels' one declaration: make_frame gives exactly the
rendered ones it stores):
  ir = sensor model (ambient + projector, its direct light x laser speckle); ambient as rendered;
  flood = ambient + flood (the projector replaced by a rectangle, as in GigaDepth's Unity sim; no
  sensor effects on either);
  depth; visibility (dotsim.masks.direct_visibility_mask: the projector's direct light, after the
  frame's exposure, above the sensor's noise) and edge masks (dotsim.masks); projector_column
  (dotsim.rig), nan where the depth is missing or beyond the rig's max_depth. disparity is not
  made here: format 2 derives it from depth on read (dotsim.dataset.frames.ground_truth_disparity).
  Of a stereo pair also: ir_right = the same sensor model of the right camera's ambient + projector,
  at the left frame's exposure (the imagers of a D400 or a Structure Core share one exposure) with a
  noise stream of its own; stereo_visibility, where the left camera's point is lit by the projector
  directly (flood_direct > 0) and seen by the right camera (dotsim.stereo.seen_by_right, from both
  cameras' depth). stereo_disparity is derived on read like disparity (format 2.1).
"""

from __future__ import annotations

import numpy as np

from dotsim.channels import rendered_channels, stored_channels
from dotsim.masks import direct_visibility_mask, edge_mask
from dotsim.rig import depth_to_projector_column
from dotsim.stereo import seen_by_right
from generator.blender.frame_recipe import RAW_PASSES
from generator.blender.geometry import NO_HIT_DEPTH
from generator.sample_scene import frame_speckle_rng
from generator.scene_spec import SceneSpec
from generator.sensor_model import SensorModel


def raw_pass_names(spec: SceneSpec) -> tuple[str, ...]:
    """The raw passes of a frame of `spec`: RAW_PASSES of each of its cameras, named with its suffix."""
    return tuple(name + camera.suffix for camera in spec.cameras for name in RAW_PASSES)


def frame_channels(spec: SceneSpec) -> tuple[str, ...]:
    """The channels of a frame of `spec` (the writer's channel list): those of one camera, or of the
    stereo pair when it renders the rig's second camera too."""
    return rendered_channels(stereo=len(spec.cameras) > 1)


def check_raw_passes(raw: dict, spec: SceneSpec, where: str) -> dict[str, np.ndarray]:
    """The raw passes of a frame of `spec` as float32 arrays of the camera's shape; ValueError naming
    what is wrong."""
    names = raw_pass_names(spec)
    missing = [name for name in names if name not in raw]
    if missing:
        raise ValueError(f"{where}: raw passes lack {missing}; expected {list(names)}")
    camera = spec.cameras[0].intrinsics
    shape = (camera.height, camera.width)
    out = {}
    for name in names:
        array = np.asarray(raw[name], dtype=np.float32)
        if array.shape != shape:
            raise ValueError(f"{where}: raw pass {name!r} has shape {array.shape}, the camera is {shape}")
        out[name] = array
    return out


# The largest value of the float16 that stores the radiance passes (dotsim/channels.py).
FLOAT16_MAX = float(np.finfo(np.float16).max)


def stored_radiance(radiance: np.ndarray) -> np.ndarray:
    """A radiance pass as its float16 channel can hold it: values beyond float16's range (a pixel or
    two of a lamp seen directly, or of a surface against the projector) saturate at its largest
    value, as a sensor saturates, instead of failing the scene's write.

    >>> stored_radiance(np.array([1.5, 1e5], np.float32)).tolist()
    [1.5, 65504.0]
    """
    return np.minimum(radiance, FLOAT16_MAX)


def make_frame(raw: dict, spec: SceneSpec, rng: np.random.Generator, where: str = "frame",
               right_rng: np.random.Generator | None = None, frame: int | None = None
               ) -> dict[str, np.ndarray]:
    """Stored channels of one frame of `spec` from its raw passes (see the module docstring): the
    spec's rig, sensor model and mask parameters decide them; `rng` draws the sensor noise, and
    `right_rng` (needed when the spec renders the stereo pair) the right camera's. frame: the frame's
    index in spec.poses, whose pose seeds the laser speckle (needed when the sensor has speckle: the
    projector's direct light is multiplied by it before the sensor sees it)."""
    rig, masks, sensor = spec.rig, spec.masks, SensorModel(spec.sensor)
    raw = check_raw_passes(raw, spec, where)
    depth = _depth(raw["depth"])
    room = ambient_scale(raw["ambient"], raw["projector"], raw["flood_direct"] > 0, spec.ambient_ratio)
    ambient = raw["ambient"] * room if room != 1.0 else raw["ambient"]
    flood = ambient + raw["flood"]
    gt_depth = np.where(depth <= rig.max_depth, depth, np.nan)
    if sensor.has_speckle and (frame is None or not 0 <= frame < len(spec.poses)):
        raise ValueError(f"{where}: frame = {frame}: the sensor's speckle needs the frame's index in the "
                         f"spec's poses, 0 to {len(spec.poses) - 1}")
    projector, projector_direct = _speckled(raw, "", sensor, spec, frame)
    signal = ambient + projector
    gain = sensor.exposure_gain(signal)  # once: the sensor model and the mask share it
    visibility = direct_visibility_mask(
        projector_direct, raw["flood_direct"], signal - projector_direct,
        gain, sensor, masks.visibility_margin, sensor.blur_px,
    ) & np.isfinite(depth)
    made = {
        "ir": sensor.apply(signal, rng, gain),
        "ambient": stored_radiance(ambient),
        "flood": stored_radiance(flood),
        "depth": depth,
        "visibility": visibility,
        "edge": edge_mask(depth, masks.edge_threshold, masks.edge_dilation),
        "projector_column": depth_to_projector_column(gt_depth, rig),
    }
    if len(spec.cameras) > 1:
        if right_rng is None:
            raise ValueError(f"{where}: the spec renders the stereo pair; the right camera needs a noise "
                             f"stream of its own (right_rng)")
        right = spec.cameras[1]
        right_ambient = raw["ambient_right"] * room if room != 1.0 else raw["ambient_right"]
        right_signal = right_ambient + _speckled(raw, right.suffix, sensor, spec, frame)[0]
        made["ir_right"] = sensor.apply(right_signal, right_rng, gain)
        made["stereo_visibility"] = (raw["flood_direct"] > 0) & seen_by_right(
            depth, _depth(raw["depth_right"]), right.intrinsics.fx, right.translation[0])
    return {name: made[name] for name in stored_channels(frame_channels(spec))}


def ambient_projector_ratio(ambient: np.ndarray, projector: np.ndarray, reached: np.ndarray) -> float | None:
    """Mean ambient light over mean projector light, both where the projector reaches (fit-sensor's
    ambient / projector statistic: a recording's projector-off over on - off); None where that is
    undefined (the projector reaches nothing, or adds no light there).

    >>> ambient, projector = np.full((2, 2), 0.5), np.array([[1.0, 0.0], [1.0, 0.0]])
    >>> ambient_projector_ratio(ambient, projector, projector > 0)
    0.5
    """
    if not reached.any():
        return None
    light = float(projector[reached].mean())
    return float(ambient[reached].mean()) / light if light > 0 else None


def ambient_scale(ambient: np.ndarray, projector: np.ndarray, reached: np.ndarray,
                  ratio: float | None) -> float:
    """The factor that brings ambient_projector_ratio to `ratio`; 1 when ratio is None or the frame's
    own ratio is undefined or 0 (no ambient light to scale).

    >>> ambient, projector = np.full((2, 2), 0.5), np.array([[1.0, 0.0], [1.0, 0.0]])
    >>> ambient_scale(ambient, projector, projector > 0, 4.0)   # 4 / 0.5
    8.0
    """
    if ratio is None:
        return 1.0
    current = ambient_projector_ratio(ambient, projector, reached)
    return ratio / current if current else 1.0


def _speckled(raw: dict, suffix: str, sensor: SensorModel, spec: SceneSpec, frame: int | None):
    """(projector, projector_direct) of one camera (its raw passes' `suffix`) with the laser speckle
    on the direct light, or as rendered without speckle. Each camera has a field of its own: speckle
    is seen through the camera's own aperture, and two imagers centimetres apart see uncorrelated
    speckle (Goodman 2007)."""
    projector, direct = raw["projector" + suffix], raw["projector_direct" + suffix]
    if not sensor.has_speckle:
        return projector, direct
    camera = 1 if suffix else 0
    speckled = direct * sensor.speckle(direct.shape, frame_speckle_rng(spec.seed, spec.poses[frame], camera))
    return projector + (speckled - direct), speckled


def _depth(raw_depth: np.ndarray) -> np.ndarray:
    """Planar depth (float32, metres) of a raw depth pass, inf where nothing is hit."""
    return np.where(raw_depth >= NO_HIT_DEPTH, np.inf, raw_depth).astype(np.float32)
