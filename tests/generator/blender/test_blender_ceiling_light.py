"""[lighting] ceiling_light with real Cycles: the panel under the ceiling lights a wall as a Lambertian
rectangle does (the irradiance integrated over the panel in numpy, independent of Blender), and far more
evenly than a point light (docs/RENDERING.md "Even ambient light")."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from dotsim.rig.geometry import Intrinsics, backproject
from dotsim.rig.presets import get_preset
from generator.blender import demo_scenes as ds
from generator.scene_spec import SceneSpec

pytest.importorskip("bpy")

FULL = get_preset("structure_core")
RIG = replace(FULL, camera=Intrinsics(1216, 896, 1115.44, 1115.44, 604.0, 457.0)).scaled(0.0625)
WALL = 2.0  # the wall's distance ahead of the camera (world y), m
CEILING = 1.2  # the panel's height over the camera, m
PANEL = (3.0, 1.6)  # its extents along world x and y, m
CENTRE = [0.0, 1.0, CEILING]  # the panel's centre (and the point lamp's), m
# The camera looks along world +y with the image's down along world -z (Blender's z is up).
WORLD_FROM_CAMERA = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])


def panel_irradiance(points: np.ndarray, steps: int = 200) -> np.ndarray:
    """Irradiance (up to a constant) of wall points (..., 3) on the plane y = WALL, facing -y, from a
    Lambertian rectangle at z = CEILING facing down: the integral of cos(emitter) cos(wall) / r^2 over
    the panel by the midpoint rule; the panel's part behind the wall gives nothing."""
    du, dv = PANEL[0] / steps, PANEL[1] / steps
    qx = CENTRE[0] - PANEL[0] / 2 + (np.arange(steps) + 0.5) * du
    qy = CENTRE[1] - PANEL[1] / 2 + (np.arange(steps) + 0.5) * dv
    qx, qy = np.meshgrid(qx, qy)
    p = points.reshape(-1, 3)
    out = np.empty(len(p))
    for k, (x, y, z) in enumerate(p):
        r2 = (qx - x) ** 2 + (qy - y) ** 2 + (CEILING - z) ** 2
        out[k] = np.sum((CEILING - z) * np.clip(WALL - qy, 0, None) / r2**2) * du * dv
    return out.reshape(points.shape[:-1])


def blocks(image: np.ndarray, size: int = 4) -> np.ndarray:
    """Means of `size` x `size` blocks."""
    h, w = (n // size * size for n in image.shape)
    return image[:h, :w].reshape(h // size, size, w // size, size).mean(axis=(1, 3))


def wall_scene(pattern, lights: list[dict]) -> SceneSpec:
    dots, path = pattern
    spec = ds.base_spec(RIG.to_dict(), path, dots.sha256, samples=16, world_strength=0.0, lights=lights,
                        poses=[WORLD_FROM_CAMERA.tolist()], pixel_scale=RIG.camera.width / FULL.camera.width)
    spec["objects"] = [ds.primitive("wall", "plane", (100.0, 100.0, 0.0), (0.0, WALL, 0.0),
                                    rotation=(math.pi / 2, 0.0, 0.0),
                                    mat=ds.material(albedo=0.8, roughness=1.0, specular=0.0))]
    return SceneSpec.from_dict(spec)


def test_ceiling_panel_lights_the_wall_as_a_lambertian_rectangle_and_evenly(renderer, pattern):
    panel = {"type": "CEILING", "location": CENTRE, "size": list(PANEL), "power": 400.0}
    frame = renderer.render(wall_scene(pattern, [panel]))[0]
    np.testing.assert_allclose(frame["depth"], WALL, rtol=1e-5)
    camera_points = backproject(frame["depth"], RIG.camera)
    world = camera_points @ WORLD_FROM_CAMERA[:3, :3].T
    expected = panel_irradiance(world)
    # one constant (power, albedo, pi) carries the integral onto the rendering everywhere, where the
    # image spans irradiances over 4x from its top to its bottom row: no trend along the rows or the
    # columns, and the 4 x 4 blocks scatter about it by their 16 samples a pixel alone
    ratio = blocks(frame["ambient"]) / blocks(expected)
    ratio /= np.median(ratio)
    assert expected.max() / expected.min() > 4.0
    for axis in (0, 1):
        assert np.abs(np.median(ratio, axis=axis) - 1).max() < 0.03, np.median(ratio, axis=axis)
    assert np.percentile(np.abs(ratio - 1), 95) < 0.06

    point = {"type": "POINT", "location": CENTRE, "power": 40.0, "radius": 0.02}
    lamp = renderer.render(wall_scene(pattern, [point]))[0]["ambient"]

    def spread(ambient: np.ndarray) -> float:
        return float(np.percentile(ambient, 90) / np.percentile(ambient, 10))
    assert spread(frame["ambient"]) < 0.8 * spread(lamp), (spread(frame["ambient"]), spread(lamp))
