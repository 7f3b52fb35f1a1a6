"""What the add-on shows, computed without bpy: the SceneSpec `dotsim generate` would render, and
the preview images of a rendered frame.

Sampling composes the generator's own public functions (config loading, pattern, built-in
textures or asset cache, `sample_scene_spec`) the way `generator.pipeline.generate` does, so the
spec is the one the dataset would hold. The only difference is where the pattern and the built-in
textures live: `work_dir` instead of the dataset folder, so spec paths differ while everything the
random stream decides (objects, materials, lights, poses) is identical.
"""

from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

import numpy as np

from dotsim.pattern_store import make_pattern
from generator.config import Config, ConfigError, load_config
from generator.pipeline import builtin_textures, cached_assets
from generator.post_render import make_frame
from generator.scene_spec import SceneResources, build_rig, frame_sensor_rng, sample_scene_spec

FRAMES_PER_SCENE = 4


def prepare_resources(config: Config, split: str, work_dir: str | os.PathLike) -> SceneResources:
    """The pattern and textures a scene of `split` refers to, written under `work_dir` once.

    The pattern file is named by its sha256, so configs with different patterns never share one;
    built-in textures are reused when present (same name, same image). Raises ConfigError naming
    the config when its pattern or asset cache cannot be used.
    """
    from dotsim.patterns import PatternError

    work_dir = Path(work_dir)
    rig = build_rig(config)
    try:
        pattern = make_pattern(config.pattern, rig.projector.width, rig.projector.height)
    except PatternError as exc:
        raise ConfigError(f"{config.source}: [pattern]: {exc}") from None
    pattern_path = work_dir / f"pattern_{pattern.sha256[:16]}.png"
    if not pattern_path.exists():
        pattern.save_png(pattern_path)
    if config.assets.source == "cache":
        assets = cached_assets(config, split)
    else:
        assets = SceneResources("", "", textures=builtin_textures(work_dir, split))
    return replace(assets, pattern_path=str(pattern_path), pattern_sha256=pattern.sha256)


def load_spec(config_path: str | os.PathLike, split: str, scene_index: int, base_seed: int,
              work_dir: str | os.PathLike) -> tuple[Config, dict]:
    """(config, SceneSpec dict) of scene `scene_index` of `split` with base seed `base_seed`, as
    `dotsim generate --config CONFIG --split SPLIT --seed BASE_SEED` samples it.

    Raises ConfigError naming the file when the config is missing or invalid, or an argument is
    out of range.
    """
    if not str(config_path).strip():
        raise ConfigError("no config file chosen; allowed: a generator TOML file such as configs/tiny.toml")
    if split not in ("train", "test"):
        raise ConfigError(f"split {split!r}: allowed: train or test")
    for name, value in (("scene index", scene_index), ("base seed", base_seed)):
        if value < 0:
            raise ConfigError(f"{name} {value}: allowed: an integer >= 0")
    config = load_config(config_path)
    resources = prepare_resources(config, split, work_dir)
    return config, sample_scene_spec(config, scene_index, base_seed, split, resources).to_dict()


def check_frame(frame: int) -> int:
    """`frame` if it names one of a scene's four rig poses, else ValueError saying what is allowed."""
    if not 0 <= frame < FRAMES_PER_SCENE:
        raise ValueError(f"frame {frame}: allowed: 0 to {FRAMES_PER_SCENE - 1}")
    return frame


def preview_images(raw: dict[str, np.ndarray], config: Config, spec: dict, base_seed: int,
                   frame_index: int) -> tuple[np.ndarray, np.ndarray, float]:
    """(ir, depth_display, depth_scale) of rendered frame `frame_index`, each (H, W) float32.

    ir: the IR channel `dotsim generate` stores for this frame (generator.post_render: sensor model
    of ambient + projector, levels in [0, 1], the same noise).
    depth_display: planar depth / depth_scale in [0, 1], 0 where nothing is hit; depth_scale is
    the largest finite depth in metres (1 when nothing is hit), so metres = value * depth_scale.
    """
    rig = build_rig(config)
    rng = frame_sensor_rng(base_seed, spec["scene_index"], check_frame(frame_index))
    frame = make_frame(raw, rig, config, rng, where=f"scene {spec['scene_index']} frame {frame_index}")
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
