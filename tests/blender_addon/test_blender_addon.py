"""The Blender add-on with real bpy: register it, drive it through bpy.ops, check what it builds and
renders against `dotsim generate`'s own output and against independent geometry.

Reference data: one tiny scene rendered by the real pipeline (`generator.driver.generate`, in its
own worker process). The add-on's work folder is that dataset, so texture paths agree too.
The module never resets Blender's factory settings (other bpy test modules share the process);
it removes what it made when it is done.
"""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from tests.blender_addon.generated_scene import BASE_SEED, CONFIG, SCENE_INDEX, SPLIT

bpy = pytest.importorskip("bpy")
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402

import blender_addon  # noqa: E402  (needs bpy)

# A Blender camera looks down its local -Z with +Y up; OpenCV's looks down +z with y down. The same
# camera's Blender object matrix is therefore its OpenCV pose with the y and z columns negated.
OPENCV_TO_BLENDER = np.diag([1.0, -1.0, -1.0, 1.0])


@pytest.fixture(scope="module")
def settings(dataset_scene):
    """The registered add-on's settings pointing at the tiny scene; everything undone afterwards."""
    window = bpy.context.window
    user_scene = window.scene
    blender_addon.register()
    settings = bpy.context.window_manager.dotsim
    settings.config = "FILE"
    settings.config_path = str(CONFIG)
    settings.split = SPLIT
    settings.scene_index = SCENE_INDEX
    settings.base_seed = BASE_SEED
    settings.frame = 0
    settings.work_dir = str(dataset_scene[0])
    yield settings
    blender_addon.unregister()
    window.scene = user_scene
    for scene in [s for s in bpy.data.scenes if s.name.startswith("dotsim preview")]:
        bpy.data.scenes.remove(scene)
    for name in ("dotsim preview", "dotsim preview depth"):
        if name in bpy.data.images:
            bpy.data.images.remove(bpy.data.images[name])
    if "dotsim spec" in bpy.data.texts:
        bpy.data.texts.remove(bpy.data.texts["dotsim spec"])


def _spec_from_text() -> dict:
    return json.loads(bpy.data.texts["dotsim spec"].as_string())


def _grey_pixels(name: str) -> np.ndarray:
    """(H, W) red channel of an image datablock, row 0 = top."""
    image = bpy.data.images[name]
    width, height = image.size
    pixels = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(height, width, 4)[::-1, :, 0]


def _intrinsics(spec: dict) -> tuple[int, int, np.ndarray]:
    camera = spec["rig"]["camera"]
    K = np.array([[camera["fx"], 0.0, camera["cx"]], [0.0, camera["fy"], camera["cy"]], [0.0, 0.0, 1.0]])
    return camera["width"], camera["height"], K


def test_show_spec_is_the_spec_dotsim_generate_rendered(settings, dataset_scene):
    out, meta, _ = dataset_scene
    assert bpy.ops.dotsim.show_spec() == {"FINISHED"}
    spec = _spec_from_text()
    assert spec["scene_index"] == SCENE_INDEX and spec["split"] == SPLIT
    for key in ("seed", "rig", "poses", "lights", "projector", "flood", "world", "render"):
        assert spec[key] == meta[key], key
    # The dataset stores texture paths relative to itself.
    stored = json.loads(json.dumps(meta["objects"]))
    for obj in stored:
        if obj["material"]["texture"] is not None:
            obj["material"]["texture"]["path"] = str(out / obj["material"]["texture"]["path"])
    assert spec["objects"] == stored
    assert spec["pattern"]["sha256"] == meta["pattern"]["sha256"]
    assert "spec of scene 1" in settings.status


def test_build_scene_places_objects_camera_and_projector(settings):
    settings.frame = 0
    assert bpy.ops.dotsim.build_scene() == {"FINISHED"}
    spec = _spec_from_text()
    scene = bpy.context.window.scene
    assert scene.name.startswith("dotsim preview")
    # Other bpy tests in this process may own objects of the same names: Blender then appends ".001".
    (content,) = [c.objects for c in scene.collection.children]
    meshes = sorted(re.sub(r"\.\d{3}$", "", o.name) for o in content if o.type == "MESH")
    assert meshes == sorted(o["name"] for o in spec["objects"])
    assert sum(o.type == "LIGHT" for o in content) == len(spec["lights"])
    assert f"{len(spec['objects'])} objects" in settings.status

    pose = np.array(spec["poses"][0])
    camera = scene.camera
    np.testing.assert_allclose(np.array(camera.matrix_world), pose @ OPENCV_TO_BLENDER, atol=1e-5)
    width, height, K = _intrinsics(spec)
    assert (scene.render.resolution_x, scene.render.resolution_y) == (width, height)
    # Blender's own projection of points in front of the camera (it reads lens, sensor fit and
    # shift) must agree with the OpenCV pinhole K [R | t] of the spec, to a thousandth of a pixel.
    rng = np.random.default_rng(0)
    points_cam = np.column_stack([rng.uniform(-1, 1, 20), rng.uniform(-0.7, 0.7, 20), rng.uniform(1, 5, 20)])
    points_world = (pose[:3, :3] @ points_cam.T).T + pose[:3, 3]
    expected = (K @ points_cam.T).T
    expected = expected[:, :2] / expected[:, 2:]
    from mathutils import Vector
    for point, (u, v) in zip(points_world, expected, strict=True):
        x, y, _ = world_to_camera_view(scene, camera, Vector(point.tolist()))
        # normalised view coordinates run from the bottom-left corner; pixel centres at +0.5
        assert x * width - 0.5 == pytest.approx(u, abs=1e-3)
        assert (1.0 - y) * height - 0.5 == pytest.approx(v, abs=1e-3)
    # The projector rides on the camera: its centre is the camera's plus the rig translation
    # (camera axes), and it looks the same way (identity rig rotation).
    (projector,) = [o for o in scene.collection.objects if o.type == "LIGHT"]
    offset = np.array(spec["rig"]["projector_translation"])
    np.testing.assert_allclose(np.array(projector.matrix_world.translation),
                               pose[:3, :3] @ offset + pose[:3, 3], atol=1e-5)
    assert np.array(spec["rig"]["projector_rotation"]) == pytest.approx(np.eye(3))
    np.testing.assert_allclose(np.array(projector.matrix_world)[:3, :3],
                               (pose @ OPENCV_TO_BLENDER)[:3, :3], atol=1e-5)


def test_frame_setting_moves_the_rig(settings):
    spec = _spec_from_text()
    settings.frame = 3
    camera = bpy.context.window.scene.camera
    np.testing.assert_allclose(np.array(camera.matrix_world), np.array(spec["poses"][3]) @ OPENCV_TO_BLENDER,
                               atol=1e-5)
    settings.frame = 0


@pytest.mark.parametrize("frame", [0, 2])
def test_preview_frame_is_the_dataset_frame(settings, dataset_scene, frame):
    _, _, frames = dataset_scene
    settings.frame = frame
    assert bpy.ops.dotsim.preview_frame() == {"FINISHED"}
    spec = _spec_from_text()
    width, height, K = _intrinsics(spec)
    ir = _grey_pixels("dotsim preview")
    depth_image = bpy.data.images["dotsim preview depth"]
    depth = _grey_pixels("dotsim preview depth") * depth_image["depth_scale_m"]
    assert ir.shape == depth.shape == (height, width)
    assert np.all(np.isfinite(ir)) and np.all(np.isfinite(depth))
    assert 0.0 <= ir.min() and ir.max() <= 1.0 and ir.std() > 0.01
    # Same renderer, spec, Cycles seed and sensor noise as the pipeline: equal up to the dataset's
    # float16 storage of IR (half a step near 0.5 is 2.4e-4).
    np.testing.assert_allclose(ir, frames[frame]["ir"].astype(np.float32), atol=2.5e-4)

    # Depth against Blender's BVH ray casts through pixel centres (independent of Cycles): planar
    # depth = hit distance along the unit ray / length of the ray with z = 1 (OpenCV camera).
    scene = bpy.context.window.scene
    pose = np.array(spec["poses"][frame])
    depsgraph = bpy.context.evaluated_depsgraph_get()
    from mathutils import Vector
    rows, columns = np.meshgrid(np.arange(4, height, 9), np.arange(4, width, 9), indexing="ij")
    relative_errors = []
    for i, j in zip(rows.ravel(), columns.ravel(), strict=True):
        ray_cam = np.linalg.solve(K, [j, i, 1.0])
        direction = pose[:3, :3] @ ray_cam
        hit, location, *_ = scene.ray_cast(depsgraph, Vector(pose[:3, 3].tolist()),
                                           Vector((direction / np.linalg.norm(direction)).tolist()))
        assert hit
        planar = np.linalg.norm(np.array(location) - pose[:3, 3]) / np.linalg.norm(ray_cam)
        relative_errors.append(abs(depth[i, j] - planar) / planar)
    relative_errors = np.array(relative_errors)
    print(f"frame {frame}: depth vs ray cast, median rel. error {np.median(relative_errors):.2e}, "
          f"share within 0.1% {np.mean(relative_errors < 1e-3):.3f}")
    # The Z pass takes each pixel's first sample, which need not pass through its centre: a few
    # pixels on slanted surfaces or edges may differ.
    assert np.median(relative_errors) < 1e-5
    assert np.mean(relative_errors < 1e-3) > 0.9
    assert f"frame {frame} of scene 1" in settings.status


def test_build_after_the_preview_scene_was_deleted(settings):
    bpy.data.scenes.remove(bpy.context.window.scene)
    assert bpy.ops.dotsim.build_scene() == {"FINISHED"}
    scene, spec = bpy.context.window.scene, _spec_from_text()
    assert scene.name.startswith("dotsim preview")
    assert len(scene.collection.children[0].objects) == len(spec["objects"]) + len(spec["lights"])


@pytest.mark.parametrize("operator", ["build_scene", "preview_frame", "show_spec"])
def test_missing_config_is_an_error_report_naming_the_file(settings, tmp_path, operator):
    missing = tmp_path / "no_such_config.toml"
    settings.config_path = str(missing)
    try:
        with pytest.raises(RuntimeError, match="no_such_config.toml: config file not found"):
            getattr(bpy.ops.dotsim, operator)()
        assert settings.status.startswith("error: ") and str(missing) in settings.status
    finally:
        settings.config_path = str(CONFIG)


def test_invalid_config_value_is_named(settings, tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("[rig]\nscale = 3.0\n")
    settings.config_path = str(bad)
    try:
        with pytest.raises(RuntimeError, match=r"bad.toml: \[rig\] scale = 3.0: out of range"):
            bpy.ops.dotsim.build_scene()
    finally:
        settings.config_path = str(CONFIG)


def test_rig_drop_down_and_rig_file(settings, tmp_path):
    """The rig choice works as `dotsim generate --rig`: a preset, or a rig file (here written by
    cv2.FileStorage, an OpenCV stereo calibration); an empty rig file field is an error report."""
    import cv2

    from dotsim.rig.presets import get_preset

    path = tmp_path / "mine.yaml"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("K1", np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])),
                       ("K2", np.array([[1000.0, 0, 799.5], [0, 1000.0, 599.5], [0, 0, 1]])),
                       ("R", np.eye(3)), ("T", np.array([[-0.07], [0.0], [0.0]])),
                       ("image_width", 640), ("image_height", 480), ("projector_width", 1600),
                       ("projector_height", 1200)):
        storage.write(key, value)
    storage.release()
    try:
        settings.rig = "kinect_v1"
        assert bpy.ops.dotsim.show_spec() == {"FINISHED"}
        assert _spec_from_text()["rig"]["camera"] == get_preset("kinect_v1").scaled(0.1).camera.to_dict()
        settings.rig = "FILE"
        settings.rig_path = ""
        with pytest.raises(RuntimeError, match="no rig file chosen"):
            bpy.ops.dotsim.show_spec()
        settings.rig_path = str(path)
        assert bpy.ops.dotsim.show_spec() == {"FINISHED"}
        rig = _spec_from_text()["rig"]
        assert (rig["camera"]["width"], rig["camera"]["fx"]) == (64, 50.0)
        assert rig["projector_translation"] == [0.07, 0.0, 0.0]
        settings.config = "tiny"  # the built-in config, by name
        assert bpy.ops.dotsim.show_spec() == {"FINISHED"}
    finally:
        settings.rig, settings.config = "CONFIG", "FILE"


def test_unregister_removes_operators_and_settings(settings):
    assert hasattr(bpy.types, "DOTSIM_PT_preview") and bpy.types.DOTSIM_PT_preview.bl_category == "dotsim"
    blender_addon.unregister()
    try:
        assert not hasattr(bpy.types.WindowManager, "dotsim")
        assert not hasattr(bpy.types, "DOTSIM_OT_build_scene")
        assert not hasattr(bpy.types, "DOTSIM_PT_preview")
        with pytest.raises((AttributeError, RuntimeError)):
            bpy.ops.dotsim.show_spec()
    finally:
        blender_addon.register()  # the fixture unregisters at the end

