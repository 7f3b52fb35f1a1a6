"""[lighting] ambient_ratio with real Cycles: the ambient pass alone is denoised before the post-render
scales it (frame_recipe.py), so a room lit to the ratio is not speckled with the path tracer's fireflies
amplified hundreds of times, and the projector's passes stay as rendered. Judged against the same scene
rendered raw with 16 times the samples (docs/RENDERING.md "Denoised ambient")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.ndimage import median_filter

from dotsim.config_schema import read_toml
from dotsim.configs import config_path
from generator.config import config_from_dict
from generator.resources import resources_in_folder
from generator.run_request import RunRequest
from generator.sample_scene import sample_scene_spec

pytest.importorskip("bpy")


def firefly_share(ambient: np.ndarray, where: np.ndarray) -> float:
    """The share of pixels of `where` more than 5 times the median of their 3 x 3 neighbourhood."""
    return float(np.mean((ambient > 5 * median_filter(ambient, 3))[where]))


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A sampled Kinect room of built-in primitives lit by its lamps (80 x 60, one still frame, 4 samples)
    and the same scene with [lighting] ambient_ratio = 15 (the vendored real Kinect frame's)."""
    data = read_toml(config_path("kinect"))  # as written: loading it whole needs the asset cache
    data["rig"] = {**data.get("rig", {}), "scale": 0.125}
    data["render"] = {**data.get("render", {}), "samples": 4, "threads": 1}
    data["assets"] = {"source": "primitives"}
    data["lighting"] = {**data.get("lighting", {}), "extra_lights": [1, 1], "ambient_ratio": [15.0, 15.0]}
    config = config_from_dict(data)
    request = RunRequest(config, tmp_path_factory.mktemp("work"), "train", scenes=1, start=0, seed=1)
    lit = sample_scene_spec(config, 0, 1, "train", resources_in_folder(config, "train", request.out,
                                                                         request.pattern))
    lit = replace(lit, poses=lit.poses[:1])
    return lit, replace(lit, ambient_ratio=None)


def test_the_lit_ambient_is_denoised_and_the_dots_are_not(renderer, room):
    """Raw at 4 samples the room's ambient (lit only by its lamp's bounces where the projector reaches) has
    many times the fireflies of a 64-sample rendering; with ambient_ratio it has no more than that
    reference, is as bright (its median within 30 %) and nearer to it than the raw one pixel by pixel.
    The passes of the projector, the flood and the depth are the raw render's, bit for bit."""
    lit_spec, dark_spec = room
    lit, dark = renderer.render(lit_spec)[0], renderer.render(dark_spec)[0]
    many = replace(dark_spec, render=replace(dark_spec.render, samples=64))
    reference = renderer.render(many)[0]["ambient"]
    reached = dark["flood_direct"] > 0
    assert reached.mean() > 0.5
    for name in ("projector", "flood", "projector_direct", "flood_direct", "depth"):
        np.testing.assert_array_equal(lit[name], dark[name], err_msg=name)

    raw, denoised, clean = (firefly_share(a, reached) for a in (dark["ambient"], lit["ambient"], reference))
    assert raw > 3 * clean, (raw, clean)
    assert denoised <= max(clean, 0.005), (denoised, clean)
    median = np.median(reference[reached])
    assert np.median(lit["ambient"][reached]) == pytest.approx(median, rel=0.3)

    def error(ambient):
        return float(np.sqrt(np.mean((ambient - reference)[reached] ** 2)))
    assert error(lit["ambient"]) < 0.5 * error(dark["ambient"])
