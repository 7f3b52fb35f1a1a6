"""Real Cycles renders at tiny sizes, checked against independent numpy geometry.

One SceneRenderer serves the whole module (as one worker serves many scenes), which also checks
that reusing the bpy scene leaks nothing from one scene into the next.
"""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
from skimage.registration import phase_cross_correlation

from dotsim.oracle import expected_pattern_image
from dotsim.rig.geometry import Intrinsics, pixel_grid, pixel_rays, reference_image
from dotsim.rig.presets import get_preset
from dotsim.sensor.model import SensorStreams
from generator.blender import demo_scenes as ds
from generator.blender.frame_recipe import RAW_PASSES, WITHOUT_DIRECT_LIGHT
from generator.post_render import make_frame
from generator.scene_spec import SceneSpec
from tests.generator.blender.box_rays import box_entry_distance, mask_core

bpy = pytest.importorskip("bpy")

# Structure Core's published principal point (604, 457) is off the image centre, so the tests also
# check Blender's lens shift signs; 1/8 scale gives a 152 x 112 camera and a 384 x 384 pattern.
FULL = get_preset("structure_core")
RIG = replace(FULL, camera=Intrinsics(1216, 896, 1115.44, 1115.44, 604.0, 457.0)).scaled(0.125)


def _spec(pattern, **kwargs) -> dict:
    dots, path = pattern
    return ds.base_spec(RIG.to_dict(), path, dots.sha256, pixel_scale=RIG.camera.width / FULL.camera.width,
                        **kwargs)


def ncc(a: np.ndarray, b: np.ndarray) -> float:
    a = a - a.mean()
    b = b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


@pytest.mark.parametrize("z", [0.9, 2.5])
def test_wall_depth_exact_and_dots_shift_by_fb_over_z(renderer, pattern, z):
    spec = _spec(pattern, samples=4)
    spec["objects"] = [ds.wall(z)]
    frame = renderer.render(SceneSpec.from_dict(spec))[0]
    np.testing.assert_allclose(frame["depth"], z, rtol=1e-6)
    # Divide out the flood (same light, same falloff) to leave the pattern; compare with the pattern
    # as seen from infinity (dotsim.rig.geometry, pure numpy), away from the borders.
    observed = frame["projector"] / frame["flood"]
    reference = reference_image(pattern[0].image, RIG, supersample=4)
    crop = (slice(12, -12), slice(16, -16))
    (dy, dx), _, _ = phase_cross_correlation(observed[crop], reference[crop], upsample_factor=100)
    expected = RIG.camera.fx * RIG.baseline / z
    # (dy, dx) is the shift that carries `reference` onto `observed`: dots move right (+u) by f b / z.
    print(f"z {z}: shift {dx:.3f} px (expected {expected:.3f}), vertical {dy:.3f}")
    assert dx == pytest.approx(expected, abs=0.1)
    assert dy == pytest.approx(0.0, abs=0.1)


def test_box_shadow_dark_and_lit_wall_matches_inverse_square(renderer, pattern):
    """A 0.2 m box at 0.5 m before a wall at 3 m: analytic ray casting says which wall pixels the
    projector cannot see. There both projector and flood are ~0; elsewhere the flood is the
    Lambertian direct light P / (4 pi^2) * albedo * cos / r^2."""
    power, albedo, wall_z = 20.0, 0.8, 3.0
    lower, upper = (-0.1, -0.1, 0.5), (0.1, 0.1, 0.7)
    spec = _spec(pattern, samples=4, projector_power=power, flood_power=power, world_strength=0.0)
    spec["objects"] = [
        ds.wall(wall_z, albedo=albedo),
        ds.primitive("box", "box", (0.2, 0.2, 0.2), (0.0, 0.0, 0.6)),
    ]
    frame = renderer.render(SceneSpec.from_dict(spec))[0]

    rays = pixel_rays(*pixel_grid(RIG.camera), RIG.camera)
    box_t = box_entry_distance(np.zeros(3), rays, lower, upper)
    on_box = np.isfinite(box_t)
    expected_depth = np.where(on_box, box_t, wall_z)  # rays have z = 1: t is planar depth
    edges = ~mask_core(~on_box) & ~mask_core(on_box)  # box silhouette +- 1 px (anti-aliased there)
    np.testing.assert_allclose(frame["depth"][~edges], expected_depth[~edges], rtol=1e-5)

    wall_points = rays * wall_z
    to_projector = RIG.t - wall_points
    shadow = ~on_box & (box_entry_distance(wall_points, to_projector, lower, upper) < 1.0)
    lit_wall = ~on_box & ~shadow
    shadow_core, lit_core = mask_core(shadow), mask_core(lit_wall)
    assert shadow_core.sum() > 100, "the test geometry should cast a visible shadow"
    r = np.linalg.norm(to_projector, axis=-1)
    cosine = wall_z / r  # wall normal (0, 0, -1) against the direction to the projector
    direct = power / (4 * math.pi**2) * albedo * cosine / r**2
    ratio = frame["flood"][lit_core] / direct[lit_core]
    # Indirect light (wall -> back of the box -> wall) adds rare bright samples at 4 spp.
    assert np.median(ratio) == pytest.approx(1.0, abs=0.005)
    assert np.mean(np.abs(ratio - 1) < 0.03) > 0.98
    for name in ("projector", "flood"):
        assert frame[name][shadow_core].max() < 0.02 * direct[lit_core].mean(), name
    assert frame["projector"][lit_core].mean() > 0.05 * direct[lit_core].mean()


def _box_shadow_scene(renderer, pattern, n_lights: int, direct_light: str = "separate"):
    """A box's cast shadow on a wall (analytic ray casting, as above) with 0-2 bright extra lights
    near the wall, 1 sample: (spec, raw passes of frame 0, shadow core, lit core), the cores 2 px
    from the silhouette and the shadow's edge (one pixel may straddle both sides)."""
    lower, upper, wall_z = (-0.1, -0.1, 0.5), (0.1, 0.1, 0.7), 1.6
    lights = [{"type": "POINT", "location": [x, -0.4, 0.8], "power": 10.0, "radius": 0.05}
              for x in (-0.6, 0.6)][:n_lights]
    spec = _spec(pattern, samples=1, projector_power=100.0, flood_power=100.0, world_strength=0.05,
                 lights=lights)
    spec["render"]["direct_light"] = direct_light
    spec["objects"] = [ds.wall(wall_z), ds.primitive("box", "box", (0.2, 0.2, 0.2), (0.0, 0.0, 0.6))]
    spec = SceneSpec.from_dict(spec)
    raw = renderer.render(spec)[0]
    rays = pixel_rays(*pixel_grid(RIG.camera), RIG.camera)
    on_box = np.isfinite(box_entry_distance(np.zeros(3), rays, lower, upper))
    wall_points = rays * wall_z
    shadow = ~on_box & (box_entry_distance(wall_points, RIG.t - wall_points, lower, upper) < 1.0)
    shadow_core, lit_core = mask_core(shadow, 2), mask_core(~on_box & ~shadow, 2)
    assert shadow_core.sum() > 50
    return spec, raw, shadow_core, lit_core


@pytest.mark.parametrize("n_lights", [2, 0])
def test_direct_light_has_no_pepper_and_the_mask_no_shadow(renderer, pattern, n_lights):
    """The box's shadow with two extra lights (or none: then the direct light comes from the
    path-traced render's own passes): the direct passes are 0 in the whole shadow and lit on every
    lit pixel (the one-render way left 5-10% of them dark, docs/RENDERING.md); the mask (make_frame)
    marks no shadow pixel visible and the lit wall visible."""
    spec, raw, shadow_core, lit_core = _box_shadow_scene(renderer, pattern, n_lights)
    assert np.count_nonzero(raw["flood_direct"][shadow_core]) == 0
    assert np.count_nonzero(raw["projector_direct"][shadow_core]) == 0
    pepper = np.mean(raw["flood_direct"][lit_core] <= 0)
    assert pepper <= 0.003, pepper
    for name in ("projector", "flood"):  # the one render's total and its passes' sum: float rounding
        assert (raw[name] >= raw[f"{name}_direct"] * (1 - 1e-6)).all(), name

    frame = make_frame(raw, spec, [SensorStreams(np.random.default_rng(0))])
    visible = frame["visibility"].astype(bool)
    assert visible[shadow_core].mean() <= 0.01
    assert visible[lit_core].mean() >= 0.97


def test_shared_direct_light_keeps_pepper_but_marks_no_shadow_visible(renderer, pattern):
    """render.direct_light = "shared" (one render per frame) on the same scene: the direct passes
    are still exactly 0 in the shadow and the mask leaves it out, but where Cycles sampled an
    extra light instead of the spot, lit pixels lack its light, and the mask leaves them out too."""
    spec, raw, shadow_core, lit_core = _box_shadow_scene(renderer, pattern, 2, "shared")
    assert np.count_nonzero(raw["flood_direct"][shadow_core]) == 0
    pepper = raw["flood_direct"][lit_core] <= 0
    assert 0.01 < pepper.mean() < 0.3, pepper.mean()
    visible = make_frame(raw, spec, [SensorStreams(np.random.default_rng(0))])["visibility"].astype(bool)
    assert not visible[shadow_core].any()
    assert not visible[lit_core][pepper].any()
    assert visible[lit_core][~pepper].mean() >= 0.97


def test_without_extra_lights_the_direct_passes_of_one_render_equal_a_direct_render(renderer, pattern):
    """Two ways to the spot's direct light on the same clutter: with no extra light, the path-traced
    render's direct passes (composited); with one of 0 W, which the direct render hides, a render of
    its own without bounces. The spot is then the only light Cycles picks, so they agree to float
    rounding, and so do the other passes."""
    spec = _clutter_spec(pattern, samples=1, world_strength=0.05)
    one = renderer.render(SceneSpec.from_dict(spec))[0]
    spec["lights"] = [{"type": "POINT", "location": [0.0, -0.5, 1.0], "power": 0.0, "radius": 0.1}]
    two = renderer.render(SceneSpec.from_dict(spec))[0]
    assert one["flood_direct"].max() > 0 and np.mean(one["flood_direct"] > 0) > 0.5
    for name in ("projector", "flood", "projector_direct", "flood_direct", "ambient", "depth"):
        np.testing.assert_allclose(one[name], two[name], rtol=1e-5, atol=1e-6, err_msg=name)


def _clutter_spec(pattern, samples: int, seed: int = 7, **kwargs) -> dict:
    spec = _spec(pattern, samples=samples, seed=seed, **kwargs)
    spec["objects"] = [ds.wall(5.0)] + ds.clutter(25, seed=seed, depth_range=(0.8, 3.5), half_fov=0.45)
    return spec


def test_clutter_projector_pass_matches_oracle(renderer, pattern):
    """Random boxes, spheres, cylinders, cones and tori before a wall: the projector pass agrees with
    dotsim.oracle's numpy projection of the pattern through the rendered depth."""
    frame = renderer.render(SceneSpec.from_dict(_clutter_spec(pattern, samples=16)))[0]
    expected = expected_pattern_image(frame["depth"], RIG, pattern[0].image, supersample=4)
    # Compare the pattern, not the shading (albedo and textures differ per object, the oracle knows
    # none of them): projector / flood (same light, same shading) against the oracle's pattern
    # lookup / its lookup of an all-white pattern.
    flat = expected_pattern_image(frame["depth"], RIG, np.ones_like(pattern[0].image), supersample=4)
    lit = mask_core((frame["flood"] > 0.05 * np.percentile(frame["flood"], 99)) & (flat > 0))
    score = ncc(frame["projector"][lit] / frame["flood"][lit], expected[lit] / flat[lit])
    # Measured here: 0.948 / 0.967 / 0.994 at 1 / 4 / 16 samples (the rest is sampling noise), the
    # same with 0 or 4 bounces; the dots shifted by one pixel score about 0.3.
    assert score > 0.985, score
    # The projector's light that bounced is kept (the direct passes hold the rest).
    for name in ("projector", "flood"):
        indirect = frame[name] - frame[f"{name}_direct"]
        assert indirect.min() >= -1e-6 * frame[name].max() and np.mean(indirect > 0) > 0.05, name


def test_switching_to_the_one_render_way_and_back_renders_the_same(renderer, pattern):
    """bench.mask_fidelity switches one renderer between the one-render way without direct passes
    (WITHOUT_DIRECT_LIGHT) and the spec's own recipe. A frame is the same before and after a switch
    there and back (Blender once left the compositor's links from passes switched off dead after
    they came back: the indirect light read as 0). With no extra light the spot is the only light
    picked in both ways, so the one render's projector and flood equal the spec's recipe's."""
    spec = SceneSpec.from_dict(_clutter_spec(pattern, samples=1))
    first = renderer.render(spec)[0]
    one = renderer.render(spec, WITHOUT_DIRECT_LIGHT)[0]
    again = renderer.render(spec)[0]
    for name in first:
        np.testing.assert_array_equal(first[name], again[name], err_msg=name)
    assert tuple(one) == WITHOUT_DIRECT_LIGHT.raw_passes and tuple(first) == RAW_PASSES  # as the recipes say
    for name in ("projector", "flood", "ambient", "depth"):
        np.testing.assert_allclose(one[name], first[name], rtol=1e-5, atol=1e-6, err_msg=name)
    assert np.mean(first["flood"] > first["flood_direct"]) > 0.01  # indirect light is there


def test_a_scene_with_extra_lights_renders_the_same_twice(renderer, pattern):
    """The direct render switches the light passes off, and the compositor is built anew after it
    (links from passes switched off and on read as 0): a second render of a scene with an extra
    light is bit-identical to the first and keeps the projector's indirect light."""
    spec = _clutter_spec(pattern, samples=1, world_strength=0.05)
    spec["lights"] = [{"type": "POINT", "location": [0.0, -0.5, 1.0], "power": 20.0, "radius": 0.1}]
    first = renderer.render(SceneSpec.from_dict(spec))
    second = renderer.render(SceneSpec.from_dict(spec))
    for a, b in zip(first, second, strict=True):
        for name in a:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert np.mean(first[-1]["flood"] > first[-1]["flood_direct"]) > 0.01  # indirect light is there


def test_same_spec_renders_bit_identical_after_another_scene(renderer, pattern):
    spec = _clutter_spec(pattern, samples=2)
    first = renderer.render(SceneSpec.from_dict(spec))[0]
    renderer.render(SceneSpec.from_dict(_clutter_spec(pattern, samples=1, seed=11)))
    second = renderer.render(SceneSpec.from_dict(spec))[0]
    for name in first:
        np.testing.assert_array_equal(first[name], second[name], err_msg=name)


@pytest.mark.parametrize("only", ["projector", "flood", "ambient"])
def test_channels_separate_exactly(renderer, pattern, tmp_path, only):
    """With only one light source on, the other two passes are exactly zero, even with glossy and
    textured (colour PNG) materials and an extra point light."""
    texture = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    texture_path = tmp_path / "texture.png"
    cv2.imwrite(str(texture_path), texture)
    on = {name: float(name == only) for name in ("projector", "flood", "ambient")}
    lights = [{"type": "POINT", "location": [0.5, -1.0, 0.5], "power": 30.0 * on["ambient"], "radius": 0.1}]
    spec = _spec(
        pattern,
        samples=2,
        projector_power=20 * on["projector"],
        flood_power=20 * on["flood"],
        world_strength=0.3 * on["ambient"],
        lights=lights,
    )
    spec["objects"] = [ds.wall(4.0)] + ds.clutter(
        12, seed=5, texture={"path": str(texture_path), "scale": 2.0, "contrast": 0.8}
    )
    for obj in spec["objects"][1::2]:
        obj["material"].update(roughness=0.1, specular=1.0)
    frame = renderer.render(SceneSpec.from_dict(spec))[0]
    assert frame[only].max() > 0
    for name in on:
        if name != only:
            assert np.count_nonzero(frame[name]) == 0, name


def test_later_poses_move_camera_and_projector_together(renderer, pattern):
    """Rig moved 0.5 m towards a wall at 2 m: frame 1 must equal a fresh render of a wall at 1.5 m
    from the origin (depth and dots), so the projector rides along with the camera."""
    moved = np.eye(4)
    moved[2, 3] = 0.5
    spec = _spec(pattern, samples=4, poses=[np.eye(4).tolist(), moved.tolist()])
    spec["objects"] = [ds.wall(2.0)]
    frames = renderer.render(SceneSpec.from_dict(spec))
    assert len(frames) == 2
    near = _spec(pattern, samples=4)
    near["objects"] = [ds.wall(1.5)]
    expected = renderer.render(SceneSpec.from_dict(near))[0]
    np.testing.assert_allclose(frames[1]["depth"], 1.5, rtol=1e-6)
    assert ncc(frames[1]["projector"], expected["projector"]) > 0.999
    assert ncc(frames[0]["projector"], expected["projector"]) < 0.5  # the dots moved by 1.5 px


def test_seed_change_alone_changes_the_render(renderer, pattern):
    """Cycles must not reuse stale settings between scenes (it did with persistent data)."""
    first, second = (_clutter_spec(pattern, samples=1, seed=7) for _ in range(2))
    second["render"]["seed"] = 8
    a, b, a_again = (renderer.render(SceneSpec.from_dict(spec))[0]["projector"]
                     for spec in (first, second, first))
    assert not np.array_equal(a, b)
    np.testing.assert_array_equal(a, a_again)


@pytest.mark.parametrize(
    "change, message",
    [
        (lambda s: s["pattern"].update(path="/nonexistent/pattern.png"), "pattern.path"),
        (lambda s: s["objects"][0]["mesh"].update(shape="pyramid"), "pyramid"),
        (
            lambda s: s["objects"][0]["mesh"].update(kind="asset", path="/nonexistent/mesh.npz"),
            "objects[0].mesh",
        ),
        (lambda s: s["render"].update(device="TPU"), "render.device"),
        (lambda s: s["projector"].update(power=-1.0), "projector.power"),
        (lambda s: s["poses"].append([[1, 0], [0, 1]]), "poses[1]"),
        (
            lambda s: s["lights"].append({"type": "SUN", "location": [0, 0, 0], "power": 1, "radius": 0}),
            "lights[0].type",
        ),
    ],
)
def test_bad_spec_errors_name_the_field(renderer, pattern, change, message):
    spec = _spec(pattern)
    spec["objects"] = [ds.wall(2.0)]
    change(spec)
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        renderer.render(SceneSpec.from_dict(spec))


def test_gpu_request_uses_a_gpu_or_falls_back_to_cpu_with_a_warning(renderer):
    import warnings

    from generator.blender.render import GPU_BACKENDS, select_device

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        backend = select_device(renderer.scene, "GPU")
    if backend == "CPU":
        assert renderer.scene.cycles.device == "CPU"
        assert any("no GPU" in str(w.message) for w in caught)
    else:
        assert backend in GPU_BACKENDS and renderer.scene.cycles.device == "GPU"
    select_device(renderer.scene, "CPU")
    assert renderer.scene.cycles.device == "CPU"
