"""The projector's defocus on real Cycles renders: dots on walls at several distances widen as the thin
lens law says (docs/CONFIG_GUIDE.md "Dot size"), measured by Gaussian fits to the dots of the stored IR.

The expected widths are computed here from the law itself (blur circle diameter fx A |1/z - 1/F| px,
a Gaussian of a quarter of it), apart from dotsim.sensor.model, and added in quadrature to the width
the same wall's dots have without defocus.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from capture.dot_statistics import find_dots, fit_dots, good_fits, isolated
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset
from dotsim.sensor.model import SensorStreams
from generator.blender import demo_scenes as ds
from generator.post_render import make_frame
from generator.scene_spec import SceneSpec

bpy = pytest.importorskip("bpy")

# Kinect v1 at 1/4 scale: a 160 x 120 camera (fx 145 px), a 400 x 300 pattern (2 pattern px per camera px).
FULL = get_preset("kinect_v1")
RIG = FULL.scaled(0.25)
APERTURE, FOCUS = 0.02, 1.5            # m: a large aperture, so the widths change by whole pixels
DISTANCES = (0.5, 1.0, 1.5, 3.0)       # blur circles of 1.9, 1.0, 0 and 1.0 px
# The measured widths follow the law within this share (Gaussian fits to about 80 dots on a pixel grid of
# the dots' own size, and the layered blur's mixture of two Gaussians).
TOLERANCE = 0.04


@pytest.fixture(scope="module")
def sparse_pattern(tmp_path_factory):
    """Isolated dots (22 pattern px apart at least: 11 camera px) of sigma 1 pattern px."""
    dots = generate_dot_pattern(RIG.projector.width, RIG.projector.height, density=0.0015, min_spacing=22.0,
                                dot_sigma=1.0, seed=5)
    path = tmp_path_factory.mktemp("pattern") / "pattern.png"
    dots.save_png(path)
    return dots, str(path)


def _ir(frame: dict, spec_dict: dict, aperture: float) -> np.ndarray:
    """The stored IR of a rendered frame through a noiseless sensor (exposed so that no dot clips) with
    the projector's defocus of `aperture` (m, focus FOCUS) and no camera blur: the dots' width is the
    pattern's and the defocus."""
    sensor = {**spec_dict["sensor"], "read_noise": 0.0, "shot_noise": 0.0, "blur_sigma": 0.0,
              "bloom_strength": 0.0, "bit_depth": 16, "auto_target": 0.1,
              "projector_aperture": aperture,
              "projector_focus": FOCUS}
    spec = SceneSpec.from_dict({**spec_dict, "sensor": sensor})
    return make_frame(frame, spec, [SensorStreams(np.random.default_rng(0))])["ir"].astype(np.float64)


def _median_sigma(ir: np.ndarray) -> tuple[float, int]:
    """The median Gaussian sigma (px) of the isolated dots that fit, and how many."""
    noise = np.full(ir.shape, 1e-3)
    centres = find_dots(ir, noise)
    inside = ((centres[:, 0] > 8) & (centres[:, 0] < ir.shape[1] - 9)
              & (centres[:, 1] > 8) & (centres[:, 1] < ir.shape[0] - 9))
    centres = centres[inside & isolated(centres, 9.0)]
    fits = fit_dots(ir, centres, 4, noise)
    fits = fits.subset(good_fits(fits))
    return float(np.median(fits.sigma)), len(fits.sigma)


def test_dot_widths_follow_the_thin_lens_law(renderer, sparse_pattern):
    dots, path = sparse_pattern
    spec_dict = ds.base_spec(RIG.to_dict(), path, dots.sha256, samples=8,
                             pixel_scale=RIG.camera.width / FULL.camera.width, world_strength=0.0)
    for z in DISTANCES:
        spec_dict["objects"] = [ds.wall(z)]
        frame = renderer.render(SceneSpec.from_dict(spec_dict))[0]
        sharp, count = _median_sigma(_ir(frame, spec_dict, 0.0))
        blurred, blurred_count = _median_sigma(_ir(frame, spec_dict, APERTURE))
        circle = RIG.camera.fx * APERTURE * abs(1 / z - 1 / FOCUS)   # px
        expected = math.hypot(sharp, circle / 4)
        print(f"z {z} m: sigma {sharp:.3f} px without defocus ({count} dots), {blurred:.3f} with "
              f"({blurred_count} dots), thin lens {expected:.3f} (circle {circle:.2f} px)")
        assert min(count, blurred_count) >= 15
        assert blurred == pytest.approx(expected, rel=TOLERANCE)
