"""What the add-on shows, computed without bpy: the SceneSpec `dotsim generate` would render, and
the preview images of a rendered frame.

Sampling uses the generator's own functions (config loading, generator/resources.py for the pattern,
built-in textures or asset cache, `sample_scene_spec`) as `dotsim generate` does, so the spec is
the one the dataset would hold. The only difference is where the pattern and the built-in textures
live: `work_dir` instead of the dataset folder, so spec paths differ while everything the random
stream decides (objects, materials, lights, poses) is identical.
"""

from __future__ import annotations

import os
from dataclasses import replace

import numpy as np

from dotsim.config_schema import ConfigError
from dotsim.rig.options import with_rig_options
from generator.config import load_config
from generator.post_render import make_frame
from generator.resources import resources_in_folder
from generator.run_request import RunRequest
from generator.sample_scene import frame_streams, sample_scene_spec
from generator.scene_spec import SceneSpec


def load_spec(config_path: str | os.PathLike, split: str, scene_index: int, base_seed: int,
              work_dir: str | os.PathLike, rig: str | None = None) -> SceneSpec:
    """The SceneSpec of scene `scene_index` of `split` with base seed `base_seed`, as
    `dotsim generate --config CONFIG [--rig RIG] --split SPLIT --seed BASE_SEED` samples it (CONFIG a
    built-in config's name or a file; RIG a preset or a rig file); its pattern and built-in textures
    are written under `work_dir` once.

    Raises ConfigError naming the file when the config is missing or invalid, or an argument is
    out of range (checked by the RunRequest of that one scene, as `dotsim generate` checks its
    options: the split as --split, the scene index as --start, the base seed as --seed).
    """
    if not str(config_path).strip():
        raise ConfigError("no config chosen; allowed: a built-in config (tiny, default, ...) or a generator "
                          "TOML file")
    config = load_config(config_path)
    if rig is not None:
        if not rig.strip():
            raise ConfigError("no rig file chosen; allowed: a rig file (dotsim rig JSON, OpenCV, ROS "
                              "camera_info or Kalibr calibration), or the config's rig or a preset")
        settings, _ = with_rig_options(config.rig, config.source, rig)
        config = replace(config, rig=settings)
    request = RunRequest(config, work_dir, split, scenes=1, start=scene_index, seed=base_seed)
    return sample_scene_spec(config, request.start, request.seed, request.split, resources_in_folder(
        config, request.split, request.out, request.pattern))


def check_frame(frame: int, spec: SceneSpec) -> int:
    """`frame` if it names one of the spec's rig poses, else ValueError saying what is allowed."""
    if not 0 <= frame < len(spec.poses):
        raise ValueError(f"frame {frame}: allowed: 0 to {len(spec.poses) - 1}")
    return frame


def preview_images(raw: dict[str, np.ndarray], spec: SceneSpec, base_seed: int,
                   frame_index: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(ir, depth_display, depth_scale) of rendered frame `frame_index`, each (H, W) float32.

    ir: the IR channel `dotsim generate` stores for this frame (generator.post_render: sensor model
    of ambient + projector, levels in [0, 1], the same noise and speckle).
    depth_display: planar depth / depth_scale in [0, 1], 0 where nothing is hit; depth_scale is
    the largest finite depth in metres (1 when nothing is hit), so metres = value * depth_scale.
    """
    check_frame(frame_index, spec)
    frame = make_frame(raw, spec, frame_streams(base_seed, spec, frame_index),
                       where=f"scene {spec.scene_index} frame {frame_index}")
    depth = frame["depth"]
    finite = np.isfinite(depth)
    depth_scale = float(depth[finite].max()) if finite.any() else 1.0
    depth_display = np.where(finite, depth / depth_scale, 0.0).astype(np.float32)
    return frame["ir"].astype(np.float32), depth_display, depth_scale


def grey_rgba_bottom_up(image: np.ndarray) -> np.ndarray:
    """Flat float32 RGBA pixels of a grey (H, W) image (row 0 = top) in Blender's order: rows bottom-up,
    alpha 1, as `bpy.types.Image.pixels.foreach_set` expects."""
    rows, columns = image.shape
    rgba = np.ones((rows, columns, 4), np.float32)
    rgba[..., :3] = image[::-1, :, None]
    return rgba.ravel()
