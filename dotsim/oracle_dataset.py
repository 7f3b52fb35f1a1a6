"""A small, geometrically exact dotsim dataset without Blender: the oracle dataset the tests and the
benchmarks train, evaluate, export and read.

Scenes are random piecewise-planar depth maps (a tilted back wall and a few nearer tilted boxes, each an
exact plane per pixel). The IR image is the oracle's prediction of the projector's light
(dotsim.oracle.expected_pattern_image, with cos/r^2 falloff and projector shadows) plus ambient light,
Gaussian noise and 12-bit quantisation; visibility comes from an oracle flood pass (an all-white pattern)
through dotsim.masks, GT column and disparity from dotsim.rig. Written with dotsim.dataset.write_scene
and sealed, so the trainer reads it exactly as it reads generator output.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from dotsim.channels import rendered_channels
from dotsim.dataset import pattern_path, seal_dataset, write_scene
from dotsim.masks import edge_mask, visibility_mask
from dotsim.oracle import expected_pattern_image
from dotsim.patterns import DotPattern, generate_dot_pattern
from dotsim.rig.geometry import Rig, depth_to_disparity, depth_to_projector_column, pixel_grid, pixel_rays
from dotsim.rig.presets import get_preset
from dotsim.rig.stereo import stereo_disparity

TINY_SCALE = 0.1  # Structure Core at 122 x 90 camera px, 307 x 307 pattern: dotsim/configs/tiny.toml's


def planar_depth(rig: Rig, z0: float, tilt_x: float, tilt_y: float) -> np.ndarray:
    """Depth (H, W) of the plane through (0, 0, z0) with normal (tilt_x, tilt_y, 1): z = z0 / n.r."""
    u, v = pixel_grid(rig.camera)
    rays = pixel_rays(u, v, rig.camera)
    denom = rays @ np.array([tilt_x, tilt_y, 1.0])
    return np.where(denom > 0.05, z0 / np.maximum(denom, 0.05), np.inf)


def random_depth(rig: Rig, rng: np.random.Generator, near: float = 0.6, far: float = 4.0) -> np.ndarray:
    """A back wall in [0.6 far, far] and 1-3 axis-aligned image rectangles with nearer planes."""
    h, w = rig.camera.height, rig.camera.width
    depth = planar_depth(rig, rng.uniform(0.6 * far, far), *rng.uniform(-0.3, 0.3, 2))
    for _ in range(rng.integers(1, 4)):
        bh, bw = rng.integers(h // 5, h // 2), rng.integers(w // 5, w // 2)
        y, x = rng.integers(0, h - bh), rng.integers(0, w - bw)
        box = planar_depth(rig, rng.uniform(near, 0.6 * far), *rng.uniform(-0.5, 0.5, 2))
        depth[y : y + bh, x : x + bw] = np.minimum(depth[y : y + bh, x : x + bw], box[y : y + bh, x : x + bw])
    return depth


def synthetic_frame(depth: np.ndarray, rig: Rig, pattern: np.ndarray, rng: np.random.Generator,
                    noise: float = 0.01, ir_bits: int = 12) -> dict[str, np.ndarray]:
    """All dotsim channels of one frame from its depth map (IR relative to the flood's 99th percentile,
    quantised to `ir_bits`)."""
    projected = expected_pattern_image(depth, rig, pattern, supersample=2)
    flood = expected_pattern_image(depth, rig, np.ones_like(pattern), supersample=2)
    scale = max(float(np.percentile(flood, 99)), 1e-12)
    ambient = np.full(depth.shape, 0.05 * rng.uniform(0.5, 1.5), np.float32)
    ir = ambient + 0.8 * projected / scale + rng.normal(0, noise, depth.shape)
    ir = np.round(np.clip(ir, 0, 1) * (2**ir_bits - 1)) / (2**ir_bits - 1)
    return {
        "ir": ir, "ambient": ambient, "flood": ambient + flood / scale, "depth": depth.astype(np.float32),
        "visibility": visibility_mask(ambient, ambient + flood / scale), "edge": edge_mask(depth),
        "projector_column": depth_to_projector_column(depth, rig),
        "disparity": depth_to_disparity(depth, rig),
    }


def pair_frame(depth: np.ndarray, rig: Rig, pattern: np.ndarray, rng: np.random.Generator,
               noise: float = 0.01, ir_bits: int = 12) -> dict[str, np.ndarray]:
    """synthetic_frame of the left camera with the channels of the rig's stereo pair: the right IR is
    the oracle's view from the second camera (the projector, B_p - B_s from it), stereo_visibility
    where both cameras see the pattern. Exact for planes whose normal has no x component (the same
    depth map from both cameras: the cameras differ by a shift along x)."""
    left = synthetic_frame(depth, rig, pattern, rng, noise, ir_bits)
    shift = np.subtract(rig.projector_translation, rig.second_camera_translation)
    right_rig = replace(rig, projector_translation=tuple(shift))
    right = synthetic_frame(depth, right_rig, pattern, rng, noise, ir_bits)
    return left | {"ir_right": right["ir"], "stereo_visibility": left["visibility"] & right["visibility"],
                   "stereo_disparity": stereo_disparity(depth, rig)}


def make_dataset(root: str | Path, scenes: int, frames_per_scene: int = 2, scale: float = TINY_SCALE,
                 seed: int = 0, test_scenes: int = 0, noise: float = 0.01, ir_bits: int = 12,
                 pair: bool = False, rig: Rig | None = None, pattern: DotPattern | None = None) -> Path:
    """Write `scenes` train scenes then `test_scenes` test scenes to root and seal it; returns root.
    pair: a RealSense D415's stereo pair (rendered_channels(stereo=True)) before planes with no x
    tilt (pair_frame), else Structure Core before random_depth's scenes. rig: another mono rig,
    used as it is (`scale` does not apply); pattern: a pattern of its projector's size instead of a
    procedural one."""
    root = Path(root)
    if rig is None:
        rig = get_preset("realsense_d415" if pair else "structure_core").scaled(scale)
    dots = pattern or generate_dot_pattern(rig.projector.width, rig.projector.height, seed=seed)
    root.mkdir(parents=True, exist_ok=True)
    dots.save_png(pattern_path(root))
    image = np.asarray(dots.image, np.float64)
    for k in range(scenes + test_scenes):
        rng = np.random.default_rng([seed, k])
        if pair:
            frames = [pair_frame(planar_depth(rig, rng.uniform(0.4, 2.0), 0.0, rng.uniform(-0.3, 0.3)), rig,
                                 image, rng, noise, ir_bits) for _ in range(frames_per_scene)]
        else:
            frames = [synthetic_frame(random_depth(rig, rng), rig, image, rng, noise, ir_bits)
                      for _ in range(frames_per_scene)]
        meta = {
            "split": "train" if k < scenes else "test", "seed": seed, "rig": rig.to_dict(),
            "pattern": {"source": dots.source, "sha256": dots.sha256, "width": rig.projector.width,
                        "height": rig.projector.height, "params": dots.params},
            "poses": [np.eye(4).tolist()] * frames_per_scene,
            "render": {"kind": "oracle (dotsim/oracle_dataset.py)", "noise": noise},
            # the noise as a config's [sensor] records it (dotsim/solvable.py reads it)
            "config": {"sensor": {"read_noise": noise, "shot_noise": 0.0, "bit_depth": ir_bits}},
        }
        write_scene(root, k, meta, frames, scenes_per_shard=3, channels=rendered_channels(pair))
    seal_dataset(root)
    return root
