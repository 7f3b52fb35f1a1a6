"""Real Cycles renders at tiny sizes of the colour camera ([render] rgb): the projector stays out of its
image, the image lies where the colour camera's calibration (written out here from the preset's numbers,
not through dotsim's projection) puts a known square, its colours are the surfaces' tints, and the IR
passes are bit for bit those of the same scene without it."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dotsim.rig.presets import PRESET_COLOUR_CAMERAS, get_preset
from generator.blender import demo_scenes as ds
from generator.post_render import make_frame
from generator.sample_scene import frame_streams
from generator.scene_spec import SceneSpec

bpy = pytest.importorskip("bpy")

SCALE = 0.125
RIG = get_preset("kinect_v1").scaled(SCALE)  # 80 x 60 px IR
COLOUR = PRESET_COLOUR_CAMERAS["kinect_v1"].scaled(SCALE)  # 80 x 60 px colour, 25 mm to the right
LAMP = {"type": "POINT", "location": [0.0, -0.3, 0.2], "power": 30.0, "radius": 0.05}


def _tinted(material: dict, tint) -> dict:
    return {**material, "tint": list(tint)}


def _spec(pattern, objects, rgb=True, **kwargs) -> SceneSpec:
    dots, path = pattern
    spec = ds.base_spec(RIG.to_dict(), path, dots.sha256, pixel_scale=SCALE, **kwargs)
    spec["render"]["rgb"] = rgb
    spec["objects"] = objects
    if rgb:
        spec["colour_camera"] = COLOUR.to_dict()
    else:
        for obj in spec["objects"]:
            obj["material"].pop("tint", None)
    return SceneSpec.from_dict(spec)


def _wall(tint, z=1.5) -> dict:
    wall = ds.wall(z, albedo=0.8)
    wall["material"] = _tinted(wall["material"], tint)
    return wall


def test_the_projector_is_invisible_to_the_colour_camera(renderer, pattern):
    """The same scene with the projector on and with it removed (power 0: not in the render at all) gives
    the very same colour image, bit for bit, while its IR shows the dots; the wall's colour in it is its
    tint (white light on a diffuse surface)."""
    tint = (1.0, 0.6, 0.3)
    on = _spec(pattern, [_wall(tint)], samples=2, lights=[LAMP])
    off = replace(on, projector_power=0.0, flood_power=0.0)
    frame_on, frame_off = renderer.render(on)[0], renderer.render(off)[0]
    assert frame_on["rgb"].shape == (COLOUR.intrinsics.height, COLOUR.intrinsics.width, 3)
    assert frame_on["projector"].max() > 0 and frame_off["projector"].max() == 0  # the dots are in the IR
    np.testing.assert_array_equal(frame_on["rgb"], frame_off["rgb"])
    means = frame_on["rgb"].reshape(-1, 3).mean(axis=0)
    assert means.min() > 0
    np.testing.assert_allclose(means / means[0], tint, rtol=1e-5)


def test_the_dots_would_show_if_the_projector_reached_the_colour_camera(renderer, pattern):
    """The check above can fail: the IR render's projector light, seen through the same camera as the
    colour image, holds the pattern's dot frequency; the colour image of that camera position holds none
    (its spectrum at the dots' spacing is no higher than at neighbouring frequencies)."""
    spec = _spec(pattern, [_wall((1.0, 1.0, 1.0), z=1.0)], samples=4, lights=[LAMP])
    frame = renderer.render(spec)[0]

    def high_frequency_share(image):
        spectrum = np.abs(np.fft.fft2(image - image.mean())) ** 2
        fy, fx = np.meshgrid(np.fft.fftfreq(image.shape[0]), np.fft.fftfreq(image.shape[1]), indexing="ij")
        return spectrum[np.hypot(fx, fy) > 0.2].sum() / spectrum.sum()

    assert high_frequency_share(frame["projector"]) > 0.5  # dots: most of the energy at fine scales
    assert high_frequency_share(frame["rgb"].mean(axis=-1)) < 0.5 * high_frequency_share(frame["projector"])


def test_a_square_lands_where_the_colour_cameras_calibration_puts_it(renderer, pattern):
    """A green square facing the rig 1 m away before a red wall: its pixels in the colour image span
    the rectangle that the Kinect v1 colour camera (f 519.2 px at 640 x 480, centre 25 mm to the right
    of the IR camera, scaled by 1/8) projects it to, and in the IR image the one the IR camera does."""
    centre, half = np.array([0.06, -0.04, 1.0]), 0.12
    square = ds.primitive("square", "plane", (2 * half, 2 * half, 0.0), centre, rotation=(np.pi, 0.0, 0.0),
                          mat=_tinted(ds.material(0.8, 1.0, 0.0), (0.0, 1.0, 0.0)))
    spec = _spec(pattern, [_wall((1.0, 0.0, 0.0), z=2.0), square], samples=4, lights=[LAMP])
    raw = renderer.render(spec)[0]
    rgb = raw["rgb"]
    green = rgb[..., 1] > rgb[..., 0]

    # independent numbers: the preset's published camera written out, Blender's centred principal point
    f, width, height, t_x = 519.2 * SCALE, 80, 60, 0.025
    cx, cy = width / 2 - 0.5, height / 2 - 0.5
    u0, u1 = f * (centre[0] - half - t_x) / centre[2] + cx, f * (centre[0] + half - t_x) / centre[2] + cx
    v0, v1 = f * (centre[1] - half) / centre[2] + cy, f * (centre[1] + half) / centre[2] + cy
    # the share of each pixel column / row the square covers (pixel j spans [j - 0.5, j + 0.5])
    cols = np.clip(np.minimum(np.arange(width) + 0.5, u1) - np.maximum(np.arange(width) - 0.5, u0), 0, 1)
    rows = np.clip(np.minimum(np.arange(height) + 0.5, v1) - np.maximum(np.arange(height) - 0.5, v0), 0, 1)
    expected = rows[:, None] * cols[None, :]
    # where the square covers a pixel wholly or not at all, the colour image agrees
    assert np.array_equal(green[expected == 1], np.ones(int((expected == 1).sum()), bool))
    assert not green[expected == 0].any()
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    assert abs(u[green].mean() - (u0 + u1) / 2) < 0.35 and abs(v[green].mean() - (v0 + v1) / 2) < 0.35

    # the 25 mm offset moves it by f t_x / z = 1.6 px, far beyond the tolerance: a camera at the IR
    # camera's centre (or on its other side) would fail the check above
    assert f * t_x / centre[2] > 4 * 0.35
    # the IR image (its own camera: f 72.5 px, no offset) has the square where that camera puts it
    seen = raw["depth"] < 1.5
    ir_u = (RIG.camera.fx * (centre[0] - half) + RIG.camera.cx,
            RIG.camera.fx * (centre[0] + half) + RIG.camera.cx)
    assert abs(u[seen].mean() - sum(ir_u) / 2) < 0.35


def test_the_ir_passes_are_those_of_the_scene_without_the_colour_camera(renderer, pattern):
    """Rendering the colour camera changes no IR pass: with an extra light (two renders per frame) and
    two poses, every raw pass of the rgb scene equals the same scene's without it, bit for bit, and its
    stored frame too (the rgb channel aside)."""
    pose = np.eye(4)
    pose[:3, 3] = (0.02, -0.01, 0.0)
    objects = [_wall((0.9, 0.5, 0.2)), *[{**obj, "material": _tinted(obj["material"], (0.3, 0.8, 0.5))}
                                         for obj in ds.clutter(6, seed=2, depth_range=(0.6, 1.3))]]
    with_rgb = _spec(pattern, objects, lights=[LAMP], poses=[np.eye(4).tolist(), pose.tolist()])
    without = _spec(pattern, [{**obj, "material": dict(obj["material"])} for obj in objects], rgb=False,
                    lights=[LAMP], poses=[np.eye(4).tolist(), pose.tolist()])
    for k, (a, b) in enumerate(zip(renderer.render(with_rgb), renderer.render(without), strict=True)):
        assert set(a) == set(b) | {"rgb"}
        for name in b:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
        stored_a = make_frame(a, with_rgb, frame_streams(0, with_rgb, k))
        stored_b = make_frame(b, without, frame_streams(0, without, k))
        assert set(stored_a) == set(stored_b) | {"rgb"} and stored_a["rgb"].shape == (60, 80, 3)
        for name in stored_b:
            np.testing.assert_array_equal(stored_a[name], stored_b[name], err_msg=name)


def test_rgb_samples_sets_the_colour_renders_samples_alone(renderer, pattern):
    """[render] rgb_samples = 16 renders the colour camera at 16 samples: its error against a 256-sample
    render of the same scene is at least 2x smaller than at the scene's 1 sample (Monte Carlo noise falls
    as 1 / sqrt(samples): 4x), the IR passes stay those of 1 sample."""
    clutter = [{**obj, "material": _tinted(obj["material"], (0.5, 0.7, 0.9))}
               for obj in ds.clutter(5, seed=4, depth_range=(0.7, 1.2))]
    one = _spec(pattern, [_wall((1.0, 1.0, 1.0)), *clutter], samples=1, lights=[LAMP])
    many = replace(one, render=replace(one.render, rgb_samples=16))
    a, b = renderer.render(one)[0], renderer.render(many)[0]
    reference = renderer.render(replace(one, render=replace(one.render, rgb_samples=256)))[0]["rgb"]

    def error(rgb):
        return float(np.abs(rgb - reference).mean())

    assert error(b["rgb"]) < 0.5 * error(a["rgb"])
    np.testing.assert_array_equal(a["projector"], b["projector"])
    np.testing.assert_array_equal(a["ambient"], b["ambient"])


def test_a_scene_of_more_textures_than_the_material_cache_holds(renderer, pattern, tmp_path):
    """70 textured objects, more textures than the renderer's material cache keeps (64): every object
    keeps its own textured material (the cache dropped materials in use, leaving 16 of 80 objects in
    Blender's default), and the colour render gives every tinted surface its twin and leaves each
    object's infrared material as the build left it."""
    import cv2

    objects = [_wall((0.8, 0.8, 0.8))]
    for k, obj in enumerate(ds.clutter(70, seed=6, depth_range=(0.6, 1.4))):
        path = tmp_path / f"texture_{k}.png"
        cv2.imwrite(str(path), np.random.default_rng(k).integers(0, 255, (16, 16), dtype=np.uint8))
        material = {**obj["material"], "texture": {"path": str(path), "scale": 1.0, "contrast": 0.5}}
        objects.append({**obj, "material": _tinted(material, (0.2, 0.9, 0.4))})
    spec = _spec(pattern, objects, lights=[LAMP])
    renderer.setup(spec)
    meshes = [obj for obj in renderer.content.collection.objects if obj.type == "MESH"]
    slots = [obj.material_slots[0].material for obj in meshes]
    textures = {Path(node.image.filepath).name for material in slots if material is not None
                for node in material.node_tree.nodes if node.type == "TEX_IMAGE" and node.image}
    assert None not in slots and textures == {f"texture_{k}.png" for k in range(70)}
    frame = renderer.render_poses(list(spec.poses))[0]
    assert np.isfinite(frame["rgb"]).all() and frame["rgb"].mean() > 0
    assert [obj.material_slots[0].material for obj in meshes] == slots
