"""Post-render stage (pure numpy): the Blender stage's raw passes of one frame -> the stored channels.

Raw passes (generator/blender SceneRenderer.render, float32 (H, W), linear radiance):
  projector  what the dot projector adds; flood  what the uniform flood rectangle adds;
  ambient    world + extra lights (projector off); depth  planar metres, inf where nothing is hit;
  projector_direct, flood_direct  the projector's and the flood's direct light alone (included in
  projector and flood).
Stored channels (dotsim.dataset.FRAME_CHANNELS):
  ir = sensor model (ambient + projector, its direct light x laser speckle); ambient as rendered;
  flood = ambient + flood (the projector replaced by a rectangle, as in GigaDepth's Unity sim; no
  sensor effects on either);
  depth; visibility (dotsim.masks.direct_visibility_mask: the projector's direct light, after the
  frame's exposure, above the sensor's noise) and edge masks (dotsim.masks); projector_column
  (dotsim.rig), nan where the depth is missing or beyond the rig's max_depth. disparity is not
  made here: format 2 derives it from depth on read (dotsim.dataset.frames.ground_truth_disparity).
"""

from __future__ import annotations

import numpy as np

from dotsim.masks import direct_visibility_mask, edge_mask
from dotsim.rig import Rig, depth_to_projector_column
from generator.blender.geometry import NO_HIT_DEPTH
from generator.sample_scene import frame_speckle_rng
from generator.scene_spec import SceneSpec
from generator.sensor_model import SensorModel

RAW_PASSES = ("projector", "flood", "ambient", "depth", "projector_direct", "flood_direct")


def check_raw_passes(raw: dict, rig: Rig, where: str) -> dict[str, np.ndarray]:
    """The raw passes as float32 arrays of the camera's shape; ValueError naming what is wrong."""
    missing = [name for name in RAW_PASSES if name not in raw]
    if missing:
        raise ValueError(f"{where}: raw passes lack {missing}; expected {list(RAW_PASSES)}")
    shape = (rig.camera.height, rig.camera.width)
    out = {}
    for name in RAW_PASSES:
        array = np.asarray(raw[name], dtype=np.float32)
        if array.shape != shape:
            raise ValueError(f"{where}: raw pass {name!r} has shape {array.shape}, the camera is {shape}")
        out[name] = array
    return out


def make_frame(raw: dict, spec: SceneSpec, rng: np.random.Generator,
               where: str = "frame", frame: int | None = None) -> dict[str, np.ndarray]:
    """Stored channels of one frame of `spec` from its raw passes (see the module docstring): the
    spec's rig, sensor model and mask parameters decide them; `rng` draws the sensor noise. frame:
    the frame's index in spec.poses, whose pose seeds the laser speckle (needed when the sensor has
    speckle: the projector's direct light is multiplied by it before the sensor sees it)."""
    rig, masks, sensor = spec.rig, spec.masks, SensorModel(spec.sensor)
    raw = check_raw_passes(raw, rig, where)
    depth = np.where(raw["depth"] >= NO_HIT_DEPTH, np.inf, raw["depth"]).astype(np.float32)
    ambient = raw["ambient"]
    flood = ambient + raw["flood"]
    gt_depth = np.where(depth <= rig.max_depth, depth, np.nan)
    projector, projector_direct = raw["projector"], raw["projector_direct"]
    if sensor.has_speckle:
        if frame is None or not 0 <= frame < len(spec.poses):
            raise ValueError(f"{where}: frame = {frame}: the sensor's speckle needs the frame's index "
                             f"in the spec's poses, 0 to {len(spec.poses) - 1}")
        speckle = sensor.speckle(depth.shape, frame_speckle_rng(spec.seed, spec.poses[frame]))
        speckled = projector_direct * speckle
        projector, projector_direct = projector + (speckled - projector_direct), speckled
    signal = ambient + projector
    gain = sensor.exposure_gain(signal)  # once: the sensor model and the mask share it
    visibility = direct_visibility_mask(
        projector_direct, raw["flood_direct"], signal - projector_direct,
        gain, sensor, masks.visibility_margin, sensor.blur_px,
    ) & np.isfinite(depth)
    return {
        "ir": sensor.apply(signal, rng, gain),
        "ambient": ambient,
        "flood": flood,
        "depth": depth,
        "visibility": visibility,
        "edge": edge_mask(depth, masks.edge_threshold, masks.edge_dilation),
        "projector_column": depth_to_projector_column(gt_depth, rig),
    }
