"""Real Cycles renders at tiny sizes of transparent, metal and IR-dark objects, with the label and normal
passes, checked against independent numpy geometry (ray-box intersection, rotation matrices, the
oracle's projection of the pattern through a given depth)."""

from __future__ import annotations

import math
from dataclasses import replace

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dotsim.labels import MATERIAL_CLASSES
from dotsim.oracle import expected_pattern_image
from dotsim.rig.geometry import Intrinsics, pixel_grid, pixel_rays
from dotsim.rig.presets import get_preset
from generator.blender import demo_scenes as ds
from generator.post_render import make_frame
from generator.sample_scene import frame_streams
from generator.scene_spec import SceneSpec
from tests.generator.blender.box_rays import box_entry_distance, mask_core

bpy = pytest.importorskip("bpy")

FULL = get_preset("structure_core")
RIG = replace(FULL, camera=Intrinsics(1216, 896, 1115.44, 1115.44, 604.0, 457.0)).scaled(0.125)
RAYS = pixel_rays(*pixel_grid(RIG.camera), RIG.camera)  # z = 1: t along them is planar depth


def _spec(pattern, objects, labels=True, normals=False, **kwargs) -> SceneSpec:
    dots, path = pattern
    spec = ds.base_spec(RIG.to_dict(), path, dots.sha256, pixel_scale=RIG.camera.width / FULL.camera.width,
                        **kwargs)
    spec["render"].update(labels=labels, normals=normals)
    spec["objects"] = objects
    return SceneSpec.from_dict(spec)


def _box_t(lower, upper) -> np.ndarray:
    """Entry distance along the camera's rays into the box [lower, upper]; inf on a miss."""
    return box_entry_distance(np.zeros(3), RAYS, lower, upper)


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / math.sqrt((a * a).sum() * (b * b).sum()))


def _box(name, centre, size, material) -> tuple[dict, tuple, tuple]:
    """A box primitive and its (lower, upper) corners."""
    centre, size = np.asarray(centre), np.asarray(size)
    return (ds.primitive(name, "box", size, centre, mat=material),
            tuple(centre - size / 2), tuple(centre + size / 2))


def test_instance_and_material_labels_match_the_objects_silhouettes(renderer, pattern):
    """A room wall (instance 0), a metal box and an IR-dark box: the object index pass gives each
    object's place in the spec's objects + 1 exactly where ray casting says the box is seen first,
    and its material's class; the passes of the light stay what they are without the labels."""
    back = ds.wall(2.5)
    back["name"] = "wall_back"  # a room surface: instance 0
    metal, metal_lo, metal_hi = _box("metal", (-0.25, 0.0, 1.2), (0.3, 0.3, 0.3),
                                     {**ds.material(0.9, 0.05, 0.5), "kind": "metal", "ior": 1.5})
    dark, dark_lo, dark_hi = _box("dark", (0.15, 0.05, 0.9), (0.2, 0.25, 0.2),
                                  {**ds.material(0.02), "kind": "ir_dark", "ior": 1.5})
    spec = _spec(pattern, [back, metal, dark], samples=2)
    raw = renderer.render(spec)[0]
    frame = make_frame(raw, spec, frame_streams(0, spec, 0))

    t_metal, t_dark = _box_t(metal_lo, metal_hi), _box_t(dark_lo, dark_hi)
    expected = np.where(np.minimum(t_metal, t_dark) == np.inf, 0, np.where(t_dark < t_metal, 3, 2))
    inner = np.ones_like(expected, bool)
    for value in (0, 2, 3):
        inner &= ~(cv2.dilate((expected == value).astype(np.uint8), np.ones((3, 3))).astype(bool)
                   & ~(expected == value))
    assert (expected[inner] == 2).sum() > 200 and (expected[inner] == 3).sum() > 200
    np.testing.assert_array_equal(frame["instance"][inner], expected[inner])
    classes = {0: "opaque", 2: "metal", 3: "ir_dark"}
    np.testing.assert_array_equal(frame["material"][inner],
                                  [MATERIAL_CLASSES.index(classes[v]) for v in expected[inner]])
    np.testing.assert_array_equal(frame["transparent_or_mirror"][inner], expected[inner] == 2)
    assert not frame["visibility"][frame["transparent_or_mirror"].astype(bool)].any()

    # The labels and normals come from passes that change no sample: the light and depth of a scene
    # of opaque objects are bit for bit those without them.
    opaque = replace(spec, objects=tuple(replace(o, material=replace(o.material, kind="opaque"))
                                         for o in spec.objects))
    plain = renderer.render(replace(opaque, render=replace(spec.render, labels=False)))[0]
    labelled = renderer.render(replace(opaque, render=replace(spec.render, normals=True)))[0]
    assert set(labelled) == set(plain) | {"object_index", "normal_x", "normal_y", "normal_z"}
    for name in plain:
        np.testing.assert_array_equal(plain[name], labelled[name], err_msg=name)


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.5, -0.3), (-0.7, 0.4)])
def test_normals_of_a_tilted_plane_match_its_rotation(renderer, pattern, tilt):
    """A plane turned by known angles, seen from a camera that is turned too (frame 1): the normal
    channels equal the plane's normal (its rotation applied to +z, facing the camera) in the camera
    frame within 1 degree on every pixel of the plane."""
    rotation = (math.pi + tilt[0], tilt[1], 0.0)
    plane = ds.primitive("plane", "plane", (20.0, 20.0, 0.0), (0.0, 0.0, 2.0), rotation=rotation)
    turned = np.eye(4)
    turned[:3, :3] = Rotation.from_euler("xyz", [0.1, -0.15, 0.05]).as_matrix()
    spec = _spec(pattern, [plane], labels=False, normals=True, samples=2,
                 poses=[np.eye(4).tolist(), turned.tolist()])
    world_normal = Rotation.from_euler("xyz", rotation).as_matrix() @ np.array([0.0, 0.0, 1.0])
    for pose, raw in zip(spec.poses, renderer.render(spec), strict=True):
        frame = make_frame(raw, spec, frame_streams(0, spec, 0))
        expected = pose[:3, :3].T @ world_normal
        expected *= -np.sign(expected[2])  # facing the camera: Cycles turns a back face's normal
        normals = np.stack([frame[f"normal_{a}"].astype(np.float64) for a in "xyz"], axis=-1)
        seen = np.isfinite(frame["depth"])
        assert seen.mean() > 0.9 and np.isnan(normals[~seen]).all()
        angle = np.degrees(np.arccos(np.clip(normals[seen] @ expected, -1, 1)))
        assert angle.max() < 1.0, (tilt, angle.max())


@pytest.mark.parametrize("extra_light", [False, True])
def test_glass_plate_shows_the_walls_dots_and_is_the_ground_truth(renderer, pattern, extra_light):
    """A 1 cm glass plate at 1 m before a wall at 2 m: depth is the plate's (the first surface), the
    transparent_or_mirror mask marks it and the visibility mask leaves it out, while the IR through it
    shows the wall's dots: the projected pattern at the wall's depth matches there, not the pattern at
    the plate's depth. With a (dark) extra light the frame takes two renders, the path-traced one of
    which must carry the light through the glass (its transmission passes)."""
    wall_z = 2.0
    glass, lower, upper = _box("glass", (0.0, 0.0, 1.0), (0.5, 0.4, 0.01),
                               {**ds.material(1.0, 0.0, 0.5), "kind": "transparent", "ior": 1.5})
    light = {"type": "POINT", "location": [0.0, -0.5, 0.5], "power": 0.0, "radius": 0.1}
    lights = [light] if extra_light else []
    spec = _spec(pattern, [ds.wall(wall_z), glass], samples=8, world_strength=0.0, lights=lights)
    raw = renderer.render(spec)[0]
    frame = make_frame(raw, spec, frame_streams(0, spec, 0))
    t_glass = _box_t(lower, upper)
    on_glass = np.isfinite(t_glass)
    core = mask_core(on_glass, 2)
    assert core.sum() > 1000
    np.testing.assert_allclose(frame["depth"][core], t_glass[core], rtol=1e-5)
    np.testing.assert_array_equal(frame["transparent_or_mirror"].astype(bool)[mask_core(on_glass, 1)], True)
    assert not frame["transparent_or_mirror"][mask_core(~on_glass, 1)].any()
    assert frame["visibility"][on_glass].sum() == 0
    assert frame["visibility"][mask_core(~on_glass, 3)].mean() > 0.9

    dots = raw["projector"] / np.maximum(raw["flood"], 1e-9)
    at_wall = expected_pattern_image(np.full_like(frame["depth"], wall_z), RIG, pattern[0].image)
    at_plate = expected_pattern_image(np.where(on_glass, t_glass, wall_z).astype(np.float32), RIG,
                                      pattern[0].image)
    through, beside = _ncc(dots[core], at_wall[core]), _ncc(dots[~on_glass], at_wall[~on_glass])
    print(f"dots through the glass vs the wall's: {through:.3f}, vs the plate's: "
          f"{_ncc(dots[core], at_plate[core]):.3f}; beside the glass: {beside:.3f}")
    assert through > 0.8 and through > _ncc(dots[core], at_plate[core]) + 0.3
    # The light through the plate: dimmed by the Fresnel reflection of its four crossings (two
    # surfaces, there and back: (1 - R0)^4 with R0 = 0.04), not more.
    flood_ratio = np.median(raw["flood"][core]) / np.median(raw["flood"][mask_core(~on_glass, 3)])
    assert 0.75 < flood_ratio < 1.0, flood_ratio


def test_ir_dark_box_shows_no_dots(renderer, pattern):
    """An IR-dark box (albedo 0.002, matte: black flock) before a white wall, the sensor's noise on: where
    the projected pattern (the oracle, from the rendered depth) puts a dot, the IR on the box is not
    brighter than between dots by more than the noise, while on the wall it is by far; and the
    visibility mask leaves the box out."""
    dark, lower, upper = _box("dark", (0.0, 0.0, 1.3), (0.5, 0.4, 0.3),
                              {**ds.material(0.002, 0.8, 0.0), "kind": "ir_dark", "ior": 1.5})
    spec = _spec(pattern, [ds.wall(1.5, albedo=0.9), dark], samples=4, world_strength=0.0)
    raw = renderer.render(spec)[0]
    frame = make_frame(raw, spec, frame_streams(0, spec, 0))
    on_box = np.isfinite(_box_t(lower, upper))
    box, wall = mask_core(on_box, 2), mask_core(~on_box, 2) & (raw["flood_direct"] > 0)
    expected = expected_pattern_image(frame["depth"], RIG, pattern[0].image)
    ir = frame["ir"].astype(np.float64)

    def dot_contrast(region):
        """(IR at the brightest tenth of the expected dots - IR between dots) / the IR's noise there."""
        values = expected[region]
        peaks, gaps = values >= np.percentile(values, 90), values <= np.percentile(values, 30)
        between = ir[region][gaps]
        return (ir[region][peaks].mean() - between.mean()) / between.std()

    on_dark, on_wall = dot_contrast(box), dot_contrast(wall)
    print(f"dot contrast in noise sigmas: IR-dark box {on_dark:.2f}, wall {on_wall:.2f}")
    assert on_wall > 10 and on_dark < 2
    assert frame["visibility"][box].mean() < 0.02 and frame["visibility"][wall].mean() > 0.9
    assert (frame["material"][box] == MATERIAL_CLASSES.index("ir_dark")).all()


def test_mirror_shows_the_dots_of_what_it_reflects(renderer, pattern):
    """A mirror at 2.2 m turned 45 degrees reflects the camera's rays sideways onto a wall at x = -1 m
    that the projector lights: on the mirror the IR shows that wall's dots where ray tracing (the ray
    reflected off the mirror's plane, the wall point projected into the projector) puts them; depth is
    the mirror's, and the masks mark it as not visible."""
    centre, normal = np.array([0.0, 0.0, 2.2]), np.array([-1.0, 0.0, -1.0]) / math.sqrt(2)
    mirror = ds.primitive("mirror", "plane", (0.5, 0.5, 0.0), centre, rotation=(0.0, -0.75 * math.pi, 0.0),
                          mat={**ds.material(0.95, 0.0, 0.5), "kind": "metal", "ior": 1.5})
    side = ds.primitive("side", "plane", (8.0, 8.0, 0.0), (-1.0, 0.0, 2.2),
                        rotation=(0.0, 0.5 * math.pi, 0.0), mat=ds.material(0.8, 1.0, 0.0))
    spec = _spec(pattern, [mirror, side], samples=4, world_strength=0.0)
    raw = renderer.render(spec)[0]
    frame = make_frame(raw, spec, frame_streams(0, spec, 0))

    t = (centre @ normal) / (RAYS @ normal)  # the mirror's plane along each camera ray
    hits = RAYS * t[..., None]
    u_axis = np.array([1.0, 0.0, -1.0]) / math.sqrt(2)
    on_mirror = (np.abs((hits - centre) @ u_axis) < 0.25) & (np.abs(hits[..., 1]) < 0.25)
    core = mask_core(on_mirror, 2)
    assert core.sum() > 300
    np.testing.assert_allclose(frame["depth"][core], t[core], rtol=1e-5)
    assert frame["transparent_or_mirror"][core].all() and not frame["visibility"][core].any()
    reflected = RAYS - 2 * (RAYS @ normal)[..., None] * normal
    wall = hits + reflected * ((-1.0 - hits[..., :1]) / reflected[..., :1])
    in_projector = (wall - RIG.t) @ RIG.R.T
    proj = RIG.projector
    map_x = (proj.fx * in_projector[..., 0] / in_projector[..., 2] + proj.cx).astype(np.float32)
    map_y = (proj.fy * in_projector[..., 1] / in_projector[..., 2] + proj.cy).astype(np.float32)
    expected = cv2.remap(pattern[0].image.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR)
    dots = raw["projector"] / np.maximum(raw["flood"], 1e-9)
    lit = core & (raw["flood"] > 0.2 * np.median(raw["flood"][core]))
    match = _ncc(dots[lit], expected[lit])
    on_surface = expected_pattern_image(np.where(on_mirror, t, np.inf).astype(np.float32), RIG,
                                        pattern[0].image)
    unreflected = _ncc(dots[lit], on_surface[lit])
    print(f"dots on the mirror vs the reflected wall's pattern: {match:.3f}, vs the pattern on the mirror's "
          f"surface: {unreflected:.3f}, over {lit.sum()} px")
    assert lit.sum() > 200 and match > 0.7 and unreflected < 0.3
