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
(ambient_scale; the right camera's by the same factor: one room; the renderer denoised them first,
frame_recipe.py). Every channel made from the
ambient sees the scaled one: ir, ir_right, the stored ambient and flood, the visibility mask's noise,
and so the device_depth engine (it models the device seeing that IR); labels and normals do not
depend on light.
Stored channels (dotsim.channels, the channels' one declaration: make_frame gives exactly the
rendered ones it stores):
  ir = sensor model (ambient + projector, its direct light blurred by the projector's defocus at each
  pixel's depth and times the laser speckle); ambient as rendered
  (or scaled, above);
  flood = ambient + flood (the projector replaced by a rectangle, as in GigaDepth's Unity sim; no
  sensor effects on either);
  depth; visibility (dotsim.masks.direct_visibility_mask: the projector's direct light, after the
  frame's exposure, above the sensor's noise) and edge masks (dotsim.masks); projector_column
  (dotsim.rig.geometry), nan where the depth is not ground truth (missing or beyond the rig's
  max_depth: dotsim.rig.geometry.is_ground_truth). disparity is not made here: format 2 derives it
  from depth on read (dotsim.dataset.frames.ground_truth_disparity).
  Of a stereo pair also: ir_right = the same sensor model of the right camera's ambient + projector,
  at the left frame's exposure (the imagers of a D400 or a Structure Core share one exposure) with a
  noise stream of its own; stereo_visibility, where the left camera's point is lit by the projector
  directly (flood_direct > 0) and seen by the right camera (dotsim.rig.stereo.seen_by_right, from both
  cameras' depth). stereo_disparity is derived on read like disparity (format 2.1).
  With [render] labels (format 2.2): instance, material and transparent_or_mirror from the object index
  pass (dotsim.labels), and the visibility mask 0 where the first surface is transparent or a mirror
  (the dots seen there lie on another surface); with [render] normals: normal_x, normal_y, normal_z;
  with [render] rgb (format 2.3): rgb, the colour camera's image as rendered (linear radiance, float16).
  With the spec's device_depth engine on, also device_depth: the depth the simulated device's chip
  reports (dotsim.device_depth; docs/DEVICE_DEPTH.md), NaN where it reports none: the stereo engine
  matches ir against ir_right, the structured-light engine ir against the reference image of the
  spec's pattern.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np

from dotsim import device_depth
from dotsim.channels import NORMAL_CHANNELS, rendered_channels, stored_channels
from dotsim.labels import object_labels
from dotsim.masks import direct_visibility_mask, edge_mask
from dotsim.patterns import load_pattern
from dotsim.rig.geometry import depth_to_projector_column, is_ground_truth
from dotsim.rig.stereo import seen_by_right
from dotsim.sensor.model import SensorModel, SensorStreams
from generator.blender.frame_recipe import LABEL_PASSES, NORMAL_PASSES, RAW_PASSES
from generator.blender.geometry import NO_HIT_DEPTH
from generator.scene_spec import SceneSpec


def raw_pass_names(spec: SceneSpec) -> tuple[str, ...]:
    """The raw passes of a frame of `spec`: RAW_PASSES of each of its cameras, named with its suffix, and
    the object index and normal passes its [render] labels and normals ask for."""
    switched = ((spec.render.labels, LABEL_PASSES), (spec.render.normals, NORMAL_PASSES))
    data = tuple(name for on, passes in switched if on for _, name in passes)
    return (tuple(name + camera.suffix for camera in spec.cameras for name in RAW_PASSES + data)
            + (("rgb",) if spec.render.rgb else ()))


def frame_channels(spec: SceneSpec) -> tuple[str, ...]:
    """The channels of a frame of `spec` (the writer's channel list): those of one camera, or of the
    stereo pair when it renders the rig's second camera too, and those of its switches that are on
    (dotsim.channels.SWITCHES: [render] labels and normals, the device depth engine)."""
    switches = {"labels": spec.render.labels, "normals": spec.render.normals,
                "device_depth": spec.device_depth.on, "rgb": spec.render.rgb}
    return rendered_channels(len(spec.cameras) > 1, tuple(name for name, on in switches.items() if on))


def frame_shapes(spec: SceneSpec) -> dict[str, tuple[int, int]]:
    """{camera: (height, width)} of the frames of `spec` (dotsim.channels.CAMERAS): the IR camera's, and
    with render.rgb the colour camera's; what dotsim.dataset.encode_frame takes as its shape."""
    camera = spec.cameras[0].intrinsics
    shapes = {"ir": (camera.height, camera.width)}
    if spec.colour_camera is not None:
        shapes["colour"] = (spec.colour_camera.intrinsics.height, spec.colour_camera.intrinsics.width)
    return shapes


def check_raw_passes(raw: dict, spec: SceneSpec, where: str) -> dict[str, np.ndarray]:
    """The raw passes of a frame of `spec` as float32 arrays of the camera's shape (the colour camera's
    "rgb": its (h, w, 3)); ValueError naming what is wrong."""
    names = raw_pass_names(spec)
    missing = [name for name in names if name not in raw]
    if missing:
        raise ValueError(f"{where}: raw passes lack {missing}; expected {list(names)}")
    shapes = frame_shapes(spec)
    out = {}
    for name in names:
        array = np.asarray(raw[name], dtype=np.float32)
        shape = shapes["colour"] + (3,) if name == "rgb" else shapes["ir"]
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


def make_frame(raw: dict, spec: SceneSpec, streams: Sequence[SensorStreams], where: str = "frame"
               ) -> dict[str, np.ndarray]:
    """Stored channels of one frame of `spec` from its raw passes (see the module docstring): the
    spec's rig, sensor model and mask parameters decide them. streams: the frame's random streams, one
    SensorStreams per camera of spec.cameras (generator.sample_scene.frame_streams): each camera's
    sensor noise and, when the sensor has speckle, its laser speckle (the projector's direct light is
    multiplied by it before the sensor sees it)."""
    rig, masks, sensor = spec.rig, spec.masks, SensorModel(spec.sensor)
    raw = check_raw_passes(raw, spec, where)
    depth = _depth(raw["depth"])
    room = ambient_scale(raw["ambient"], raw["projector"], raw["flood_direct"] > 0, spec.ambient_ratio)
    ambient = raw["ambient"] * room if room != 1.0 else raw["ambient"]
    flood = ambient + raw["flood"]
    gt_depth = np.where(is_ground_truth(depth, rig.max_depth), depth, np.nan)
    if len(streams) != len(spec.cameras):
        raise ValueError(f"{where}: {len(streams)} SensorStreams for the spec's {len(spec.cameras)} "
                         f"camera(s); each camera draws from streams of its own")
    if sensor.has_speckle and any(s.speckle is None for s in streams):
        raise ValueError(f"{where}: the sensor has laser speckle (speckle_contrast > 0): every camera's "
                         f"SensorStreams needs a speckle stream")
    projector, projector_direct = _projector_light(raw, "", sensor, streams[0], depth, rig.camera.fx)
    signal = ambient + projector
    gain = sensor.exposure_gain(signal)  # once: the sensor model and the mask share it
    visibility = direct_visibility_mask(
        projector_direct, raw["flood_direct"], signal - projector_direct,
        gain, sensor, masks.visibility_margin, sensor.blur_px,
    ) & np.isfinite(depth)
    made = {}
    if spec.render.labels:
        made.update(object_labels(raw["object_index"], [obj.material.kind for obj in spec.objects],
                                  [obj.name for obj in spec.objects], where))
        visibility &= ~made["transparent_or_mirror"]
    if spec.render.rgb:
        made["rgb"] = stored_radiance(raw["rgb"])
    if spec.render.normals:
        # nan where the depth (the first sample) hit nothing, though another sample of the pixel did
        made.update({name: np.where(np.isfinite(depth), raw[name], np.nan) for name in NORMAL_CHANNELS})
    made |= {
        "ir": sensor.apply(signal, streams[0].noise, gain),
        "ambient": stored_radiance(ambient),
        "flood": stored_radiance(flood),
        "depth": depth,
        "visibility": visibility,
        "edge": edge_mask(depth, masks.edge_threshold, masks.edge_dilation),
        "projector_column": depth_to_projector_column(gt_depth, rig),
    }
    if len(spec.cameras) > 1:
        right = spec.cameras[1]
        right_ambient = raw["ambient_right"] * room if room != 1.0 else raw["ambient_right"]
        right_depth = _depth(raw["depth_right"])
        right_signal = right_ambient + _projector_light(raw, right.suffix, sensor, streams[1], right_depth,
                                                        right.intrinsics.fx)[0]
        made["ir_right"] = sensor.apply(right_signal, streams[1].noise, gain)
        made["stereo_visibility"] = (raw["flood_direct"] > 0) & seen_by_right(
            depth, right_depth, right.intrinsics.fx, right.translation[0])
    if spec.device_depth.on:
        made["device_depth"] = device_depth.as_channel(simulated_device_depth(spec, made))
    return {name: made[name] for name in stored_channels(frame_channels(spec))}


def simulated_device_depth(spec: SceneSpec, made: dict[str, np.ndarray]) -> np.ndarray:
    """The depth (float32 m, 0 = none) the spec's device engine reports for a frame's channels: the
    stereo engine on ir and ir_right (the rig's second camera), the structured-light engine on ir and
    the reference image of the spec's pattern."""
    settings, rig = spec.device_depth, spec.rig
    scale = spec.sensor.pixel_scale
    ir = made["ir"].astype(np.float32)
    if settings.engine == "stereo":
        right = spec.cameras[1]
        return device_depth.stereo_depth(ir, made["ir_right"].astype(np.float32), rig.camera.fx,
                                         right.translation[0], settings, scale)
    reference = _reference_image(spec.pattern.path, spec.pattern.sha256, rig, settings.reference_distance)
    return device_depth.structured_light_depth(ir, reference, rig.camera.fx, rig.baseline, settings, scale)


@functools.lru_cache(maxsize=2)
def _reference_image(path: str, sha256: str, rig, distance: float) -> np.ndarray:
    """The device's reference image for a pattern file (its sha256 in the key: a rewritten file is a new
    pattern), made once per worker: every frame of a run shares it."""
    pattern = load_pattern(path, (rig.projector.height, rig.projector.width))
    reference = device_depth.reference_image_at(pattern.image, rig, distance)
    reference.flags.writeable = False
    return reference


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


def _projector_light(raw: dict, suffix: str, sensor: SensorModel, streams: SensorStreams,
                     depth: np.ndarray, fx: float):
    """(projector, projector_direct) of one camera (its raw passes' `suffix`; its planar depth and focal
    length, render px) with the projector's defocus (SensorModel.defocus) and then the laser speckle on
    the direct light, or as rendered without either. Each camera has a speckle field of its own: speckle
    is seen through the camera's own aperture, and two imagers centimetres apart see uncorrelated
    speckle (Goodman 2007)."""
    projector, direct = raw["projector" + suffix], raw["projector_direct" + suffix]
    changed = direct
    if sensor.has_defocus:
        changed = sensor.defocus(direct, raw["flood_direct" + suffix], depth, fx)
    if sensor.has_speckle:
        changed = changed * sensor.speckle(direct.shape, streams.speckle)
    if changed is direct:
        return projector, direct
    return projector + (changed - direct), changed


def _depth(raw_depth: np.ndarray) -> np.ndarray:
    """Planar depth (float32, metres) of a raw depth pass, inf where nothing is hit."""
    return np.where(raw_depth >= NO_HIT_DEPTH, np.inf, raw_depth).astype(np.float32)
