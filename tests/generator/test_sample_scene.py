"""SceneSpec sampling: determinism, the contract schema, geometry checked by projecting."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from dotsim.config_schema import ConfigError
from dotsim.rig.geometry import Rig
from generator.config import config_from_dict
from generator.sample_scene import (
    MeshAsset,
    SceneResources,
    TextureAsset,
    build_rig,
    camera_rotation,
    frame_streams,
    ray_box_exit,
    sample_scene_spec,
)
from generator.scene_spec import CeilingLight, SceneSpec

RESOURCES = SceneResources("/data/pattern.png", "ab" * 32,
                           (TextureAsset("/data/t0.png"), TextureAsset("/data/t1.png", (0.5, 0.5))))
SHAPES = {"plane", "box", "sphere", "cylinder", "cone", "torus"}


def spec_dict(overrides=None, index=0, seed=0, split="train"):
    return sample_scene_spec(config_from_dict(overrides or {}), index, seed, split, RESOURCES).to_dict()


def _number(x):
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def _vec(x, n=3):
    return isinstance(x, list) and len(x) == n and all(_number(v) for v in x)


def check_contract(d: dict) -> None:
    """The JSON contract of docs/SCENE_SPEC.md, written out independently of scene_spec.py."""
    assert set(d) == {"scene_index", "split", "seed", "render", "rig", "pattern", "projector", "flood",
                      "world", "lights", "poses", "cameras", "objects", "sensor", "masks", "device_depth"}
    assert isinstance(d["scene_index"], int) and d["split"] in ("train", "test")
    assert isinstance(d["seed"], int)
    r = d["render"]
    assert set(r) == {"samples", "seed", "max_bounces", "device", "threads", "direct_light", "labels",
                      "normals", "rgb", "rgb_samples"}
    assert r["samples"] >= 1 and r["device"] in ("CPU", "GPU") and r["threads"] >= 0
    assert r["direct_light"] in ("separate", "shared")
    assert set(d["device_depth"]) == {"engine", "num_disparities", "disparity_shift", "block_size",
                                      "second_peak_threshold", "left_right_threshold", "texture_threshold",
                                      "score_threshold", "subpixel_step", "depth_unit", "reference_distance"}
    assert d["device_depth"]["engine"] in ("off", "stereo", "structured_light")
    Rig.from_dict(d["rig"])
    assert set(d["pattern"]) == {"path", "sha256"} and d["pattern"]["path"].startswith("/")
    assert set(d["projector"]) == {"power"} and d["projector"]["power"] > 0
    assert set(d["flood"]) == {"power"} and d["flood"]["power"] > 0
    assert set(d["world"]) == {"strength"} and d["world"]["strength"] >= 0
    for light in d["lights"]:
        assert set(light) == {"type", "location", "power", "radius"} and light["type"] == "POINT"
        assert _vec(light["location"]) and light["power"] >= 0 and light["radius"] >= 0
    assert len(d["poses"]) == 4
    for pose in d["poses"]:
        m = np.array(pose, dtype=float)
        assert m.shape == (4, 4) and np.allclose(m[3], [0, 0, 0, 1])
        assert np.allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-9)
        assert np.linalg.det(m[:3, :3]) > 0
    rig = Rig.from_dict(d["rig"])
    assert d["cameras"] == [{"name": "left", "intrinsics": rig.camera.to_dict(), "translation": [0, 0, 0]}]
    for obj in d["objects"]:
        assert set(obj) == {"name", "mesh", "location", "rotation_euler", "scale", "material"}
        mesh = obj["mesh"]
        if mesh["kind"] == "primitive":
            assert set(mesh) == {"kind", "shape", "size"} and mesh["shape"] in SHAPES
            assert _vec(mesh["size"]) and min(mesh["size"]) >= 0
        else:
            assert mesh["kind"] == "asset" and set(mesh) == {"kind", "path", "id"}
        assert _vec(obj["location"]) and _vec(obj["rotation_euler"]) and _vec(obj["scale"])
        mat = obj["material"]
        assert set(mat) == {"albedo", "texture", "roughness", "specular"}
        assert 0 <= mat["albedo"] <= 1 and 0 <= mat["roughness"] <= 1 and 0 <= mat["specular"] <= 1
        if mat["texture"] is not None:
            assert set(mat["texture"]) == {"path", "scale", "contrast"}
    assert len({obj["name"] for obj in d["objects"]}) == len(d["objects"])
    assert d["sensor"]["exposure"] in ("fixed", "auto") and 1 <= d["sensor"]["bit_depth"] <= 16
    assert d["sensor"]["pixel_scale"] > 0 and d["sensor"]["gain"] > 0
    assert set(d["masks"]) == {"visibility_margin", "edge_threshold", "edge_dilation"}
    json.dumps(d, allow_nan=False)  # travels as JSON to `blender --python`


def camera_points(d: dict, frame: int = 0) -> np.ndarray:
    """Object centres (excluding the six room surfaces) in the camera frame of `frame`."""
    pose = np.array(d["poses"][frame])
    world = np.array([o["location"] for o in d["objects"] if o["name"].startswith("object_")])
    return (world - pose[:3, 3]) @ pose[:3, :3]  # R^T (X - c), row-vector form


def test_spec_follows_contract():
    for index in range(3):
        check_contract(spec_dict(index=index))
    check_contract(spec_dict(split="test"))


def test_same_inputs_same_spec_and_different_index_differs():
    a, b = spec_dict(index=5, seed=11), spec_dict(index=5, seed=11)
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)
    assert json.dumps(spec_dict(index=6, seed=11)) != json.dumps(a)
    assert json.dumps(spec_dict(index=5, seed=12)) != json.dumps(a)


def test_objects_mostly_in_view_and_inside_distance_range():
    overrides = {"scene": {"object_count": [400, 400], "in_view_share": 0.8}}
    d = spec_dict(overrides, index=2)
    rig = Rig.from_dict(d["rig"])
    p = camera_points(d)
    assert len(p) == 400
    in_front = p[:, 2] > 0
    u = rig.camera.fx * p[:, 0] / p[:, 2] + rig.camera.cx
    v = rig.camera.fy * p[:, 1] / p[:, 2] + rig.camera.cy
    in_view = in_front & (u >= -0.5) & (u <= rig.camera.width - 0.5) & (v >= -0.5) & \
        (v <= rig.camera.height - 0.5)
    # 80% are placed in view; a binomial(400, 0.8) stays within +-0.06 of that with high probability.
    assert 0.74 <= in_view.mean() <= 0.86
    # The others are in the projector's view (they cast shadows the camera cannot explain).
    q = (p[~in_view] - rig.t) @ rig.R.T
    xp = rig.projector.fx * q[:, 0] / q[:, 2] + rig.projector.cx
    yp = rig.projector.fy * q[:, 1] / q[:, 2] + rig.projector.cy
    in_projector = (q[:, 2] > 0) & (xp >= -0.5) & (xp <= rig.projector.width - 0.5) & \
        (yp >= -0.5) & (yp <= rig.projector.height - 0.5)
    assert in_projector.mean() > 0.95
    distance = np.linalg.norm(p[in_view], axis=1)
    assert distance.min() >= 0.3 * 0.999 and distance.max() <= 10.0 * 1.001


def test_objects_inside_room_and_never_swallow_the_camera():
    d = spec_dict({"scene": {"object_count": [300, 300]}}, index=4)
    walls = {o["name"]: o for o in d["objects"] if not o["name"].startswith("object_")}
    w, dd = walls["floor"]["mesh"]["size"][:2]
    h = walls["ceiling"]["location"][2]
    for obj in d["objects"]:
        x, y, z = obj["location"]
        assert -w / 2 - 1e-9 <= x <= w / 2 + 1e-9 and -dd / 2 - 1e-9 <= y <= dd / 2 + 1e-9
        assert -1e-9 <= z <= h + 1e-9
    for frame in range(4):
        centre = np.array(d["poses"][frame])[:3, 3]
        for obj in d["objects"]:
            if obj["name"].startswith("object_"):
                size = np.array(obj["mesh"]["size"])
                if obj["mesh"]["shape"] == "plane":
                    size[2] = 0.0  # a plane's z size is a (thickness-less) scale, not an extent
                radius = 0.5 * np.linalg.norm(size)
                assert np.linalg.norm(np.array(obj["location"]) - centre) > radius


def test_room_planes_face_inwards():
    d = spec_dict(index=1)
    for obj in d["objects"][:6]:
        rx, ry, rz = obj["rotation_euler"]
        # Blender XYZ Euler: R = Rz Ry Rx; a plane's normal is its local +z.
        cx, sx, cy, sy, cz, sz = (math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry),
                                  math.cos(rz), math.sin(rz))
        normal = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array(
            [[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) @ np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]]) \
            @ np.array([0.0, 0.0, 1.0])
        centre = np.array([0.0, 0.0, d["objects"][1]["location"][2] / 2])  # ceiling height / 2
        assert normal @ (centre - np.array(obj["location"])) > 0, obj["name"]


def test_camera_rotation_axes():
    r = camera_rotation(0.0, 0.0, 0.0)
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 1, 0], atol=1e-12)   # looks along world +y
    np.testing.assert_allclose(r @ [1, 0, 0], [1, 0, 0], atol=1e-12)   # image right = world +x
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, -1], atol=1e-12)  # image down = world -z
    assert (camera_rotation(0.0, 0.3, 0.0) @ [0, 0, 1])[2] == pytest.approx(math.sin(0.3))
    np.testing.assert_allclose(camera_rotation(math.pi / 2, 0, 0) @ [0, 0, 1], [-1, 0, 0], atol=1e-12)


def test_ray_box_exit():
    lo, hi = np.array([-1.0, -2.0, 0.0]), np.array([1.0, 2.0, 3.0])
    assert ray_box_exit(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), lo, hi) == 2.0
    assert ray_box_exit(np.array([0.5, 0.0, 1.0]), np.array([-1.0, 0.0, -1.0]), lo, hi) == 1.0


def test_poses_move_within_motion_limits():
    d = spec_dict({"motion": {"translation": 0.05, "rotation": 2.0}}, index=3)
    base = np.array(d["poses"][0])
    for pose in d["poses"][1:]:
        delta = np.linalg.inv(base) @ np.array(pose)
        assert np.all(np.abs(delta[:3, 3]) <= 0.05 + 1e-12)
        angle = math.degrees(math.acos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        assert angle <= 2.0 + 1e-9
    assert not np.allclose(d["poses"][1], d["poses"][0])


def test_split_density_and_scaled_rig():
    overrides = {"scene": {"object_count": [200, 200]},
                 "assets": {"train_density": 1.0, "test_density": 1.5}, "rig": {"scale": 0.25}}
    train = spec_dict(overrides, split="train")
    test = spec_dict(overrides, split="test")
    assert len(train["objects"]) == 6 + 200 and len(test["objects"]) == 6 + 300
    assert train["rig"]["camera"]["width"] == 304 and train["rig"]["camera"]["height"] == 224
    rig = build_rig(config_from_dict({"rig": {"baseline": 0.05}}))
    assert rig.baseline == 0.05 and rig.camera.width == 1216


def test_textures_and_glossy_shares():
    d = spec_dict({"scene": {"object_count": [500, 500], "textured_share": 0.5, "glossy_share": 0.2}})
    objects = [o for o in d["objects"] if o["name"].startswith("object_")]
    textured = np.mean([o["material"]["texture"] is not None for o in objects])
    glossy = np.mean([o["material"]["roughness"] <= 0.2 and o["material"]["specular"] >= 0.5
                      for o in objects])
    assert 0.43 <= textured <= 0.57 and 0.14 <= glossy <= 0.26
    assert {o["material"]["texture"]["path"] for o in objects if o["material"]["texture"]} == \
        {t.path for t in RESOURCES.textures}
    # UV scale = object extent x tiles per metre: t1 has 0.5 m tiles, t0 the config's 0.5-4 per metre.
    for o in objects:
        texture = o["material"]["texture"]
        if texture:
            extent = max(o["mesh"]["size"][:2] + ([o["mesh"]["size"][2]] if o["mesh"]["shape"] != "plane"
                                                  else []))
            if texture["path"] == "/data/t1.png":
                assert texture["scale"] == pytest.approx(extent * 2.0)
            else:
                assert 0.5 * extent * 0.999 <= texture["scale"] <= 4.0 * extent * 1.001


def test_area_and_volume_distance_sampling_follow_depth_powers():
    """area: density ~ z, so P(z < x) = (x^2 - a^2) / (b^2 - a^2); volume: density ~ z^2 (cubes)."""
    from generator.sample_scene import DISTANCE_SAMPLERS

    rng = np.random.default_rng(3)
    a, b = 0.3, 10.0
    for name, power in (("uniform", 1), ("area", 2), ("volume", 3)):
        z = np.array([DISTANCE_SAMPLERS[name](rng, a, b) for _ in range(20000)])
        assert a <= z.min() and z.max() <= b
        for x in (1.0, 2.0, 5.0):
            expected = (x**power - a**power) / (b**power - a**power)
            assert abs(np.mean(z < x) - expected) < 0.01, (name, x)
    assert DISTANCE_SAMPLERS["area"](rng, 2.0, 2.0) == 2.0


def test_a_camera_facing_the_back_wall_sees_it_head_on_behind_the_objects():
    """[scene] back_wall_distance: the camera looks level along +y at the back wall from a distance
    in the range, from mid width and mid height; the objects lie between camera and wall."""
    overrides = {"scene": {"back_wall_distance": [3.0, 5.0], "room_size": [8.0, 10.0],
                           "room_height": [6.0, 6.0], "distance": [0.5, 3.0], "object_count": [20, 20],
                           "in_view_share": 1.0}}
    for index in range(5):
        d = spec_dict(overrides, index=index)
        walls = {o["name"]: o for o in d["objects"] if not o["name"].startswith("object_")}
        back_y = walls["wall_back"]["location"][1]
        pose = np.array(d["poses"][0])
        assert np.allclose(pose[:3, :3] @ [0, 0, 1], [0, 1, 0])  # optical axis along +y, level
        assert np.allclose(pose[:3, :3] @ [0, 1, 0], [0, 0, -1])  # image down = world down
        x, y, z = pose[:3, 3]
        assert 3.0 <= back_y - y <= 5.0 and x == 0.0
        assert z == pytest.approx(walls["ceiling"]["location"][2] / 2)
        depths = camera_points(d)[:, 2]
        assert len(depths) == 20 and depths.min() > 0 and depths.max() < back_y - y
    assert len({spec_dict(overrides, index=k)["poses"][0][1][3] for k in range(5)}) == 5  # drawn per scene


def test_a_frames_random_streams_are_derived_in_one_place():
    """frame_streams gives each camera of a frame its noise stream, the scene's SeedSequence((base
    seed, scene index)) spawned at (1, frame[, camera]), and its speckle stream, seeded by the scene's
    seed and the pose's 16 float64 read as 32 uint32 words (written out here), so frames of one pose
    share their speckle."""
    config = config_from_dict({"rig": {"preset": "realsense_d415", "scale": 0.05, "stereo": True}})
    spec = sample_scene_spec(config, 5, 9, "train", RESOURCES)
    spec = replace(spec, poses=(spec.poses[0], spec.poses[0], spec.poses[1], spec.poses[2]))

    def draws(generator):
        return generator.integers(0, 2**62, 4).tolist()

    for frame in range(4):
        streams = frame_streams(9, spec, frame)
        assert len(streams) == 2
        for camera, stream in enumerate(streams):
            key = (1, frame) + ((camera,) if camera else ())
            noise = np.random.default_rng(np.random.SeedSequence((9, 5), spawn_key=key))
            assert draws(stream.noise) == draws(noise)
            words = np.frombuffer(np.asarray(spec.poses[frame], "<f8").tobytes(), "<u4").tolist()
            entropy = [spec.seed, *words] + ([camera] if camera else [])
            speckle = np.random.default_rng(np.random.SeedSequence(entropy))
            assert draws(stream.speckle) == draws(speckle)
    same_pose = [draws(frame_streams(9, spec, k)[0].speckle) for k in (0, 1, 2)]
    assert same_pose[0] == same_pose[1] != same_pose[2]
    with pytest.raises(ValueError, match=r"^frame = -1: not a frame of scene 5; allowed: 0 to 3$"):
        frame_streams(9, spec, -1)


def test_ambient_ratio_is_drawn_last_and_only_when_asked_for():
    """[lighting] ambient_ratio: each scene draws its target log-uniformly in the range, after every
    other draw, so the rest of the scene is the one drawn without it; [0, 0] (the default) draws
    nothing and records nothing; a range starting at 0 is refused."""
    plain = sample_scene_spec(config_from_dict({}), 3, 0, "train", SceneResources("/p.png", "0" * 64))
    config = config_from_dict({"lighting": {"ambient_ratio": [0.1, 20.0]}})
    ratios = []
    for index in range(20):
        spec = sample_scene_spec(config, index, 0, "train", SceneResources("/p.png", "0" * 64))
        ratios.append(spec.ambient_ratio)
        if index == 3:
            lit = spec.to_dict()
            assert lit.pop("ambient_ratio") == spec.ambient_ratio and lit == plain.to_dict()
    assert plain.ambient_ratio is None and "ambient_ratio" not in plain.to_dict()
    assert all(0.1 <= r <= 20.0 for r in ratios) and min(ratios) < 1.0 < max(ratios)
    with pytest.raises(ConfigError, match=r"\[lighting\] ambient_ratio = \[0, 5\]: not allowed"):
        config_from_dict({"lighting": {"ambient_ratio": [0.0, 5.0]}})


def test_ceiling_light_hangs_one_panel_under_the_whole_ceiling_only_when_asked_for():
    """[lighting] ceiling_light: one panel per scene, its power log-uniform in the range, centred under
    the ceiling (the room's highest point, drawn as the room's other surfaces are) and 90 % of its width
    and depth, facing down; it is drawn after every other draw, so the rest of the scene is the one drawn
    without it, and [0, 0] (the default) adds nothing; a range starting at 0 is refused."""
    resources = SceneResources("/p.png", "0" * 64)
    room = {"room_size": [3.0, 9.0], "room_height": [2.5, 4.0]}
    config = config_from_dict({"scene": room, "lighting": {"extra_lights": [1, 2]}})
    panelled = config_from_dict({"scene": room, "lighting": {"extra_lights": [1, 2],
                                                             "ceiling_light": [10.0, 1000.0]}})
    powers = []
    for index in range(12):
        plain = sample_scene_spec(config, index, 0, "train", resources)
        spec = sample_scene_spec(panelled, index, 0, "train", resources)
        *lamps, panel = spec.lights
        assert isinstance(panel, CeilingLight) and tuple(lamps) == plain.lights
        assert replace(spec, lights=plain.lights) == plain
        ceiling = panel.location[2] + 0.01
        assert 2.5 <= ceiling <= 4.0 and panel.location[:2] == (0.0, 0.0)
        # the room is [-w/2, w/2] x [-d/2, d/2]: every pose stands inside 0.9 of it, with its clearance
        assert all(abs(pose[k][3]) < size / 0.9 / 2
                   for pose in spec.poses for k, size in enumerate(panel.size))
        assert all(3.0 * 0.9 <= size <= 9.0 * 0.9 for size in panel.size)
        powers.append(panel.power)
    assert all(10.0 <= p <= 1000.0 for p in powers) and min(powers) < 100.0 < max(powers)
    assert all(not isinstance(light, CeilingLight) for light in plain.lights)
    again = SceneSpec.from_dict(spec.to_dict())
    assert again.lights[-1] == panel
    with pytest.raises(ConfigError, match=r"\[lighting\] ceiling_light = \[0, 5\]: not allowed"):
        config_from_dict({"lighting": {"ceiling_light": [0.0, 5.0]}})


def test_mesh_size_draws_asset_meshes_within_their_own_range_or_object_size():
    # A cached mesh stored 2 m across with a scale hint of 0.05-0.6 m: its drawn extent is the stored
    # extent times its scale, inside the hint ("asset") or inside [scene] object_size ("object_size"),
    # and never above max_angular_size x the distance of its centre from the camera in either case.
    mesh = MeshAsset("/data/m.npz", "m", extent=2.0, size_range=(0.05, 0.6))
    resources = replace(RESOURCES, meshes=(mesh,))
    for mode, (low, high) in (("asset", (0.05, 0.6)), ("object_size", (0.5, 2.0))):
        config = config_from_dict({"scene": {
            "object_count": [300, 300], "mesh_size": mode, "object_size": [0.5, 2.0], "distance": [0.5, 3.0],
            "max_angular_size": 0.8, "in_view_share": 1.0, "back_wall_distance": [4.0, 4.0],
            "room_size": [8.0, 8.0], "room_height": [6.0, 6.0]}})
        spec = sample_scene_spec(config, 0, 0, "train", resources)
        cam = np.asarray(spec.poses[0])[:3, 3]
        objects = [o for o in spec.objects if o.name.startswith("object_")]
        extents = np.array([2.0 * o.scale[0] for o in objects])
        caps = 0.8 * np.array([np.linalg.norm(np.asarray(o.location) - cam) for o in objects])
        assert len(objects) == 300
        assert np.all(extents <= np.minimum(high, caps) + 1e-9)
        assert np.all(extents >= np.minimum(low, caps) - 1e-9)
        uncapped = caps > high
        assert extents[uncapped].max() > 0.8 * high  # the range is used, not only its low end
