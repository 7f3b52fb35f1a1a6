"""`dotsim generate` with labels, normals and transparent, metal and IR-dark objects: a real tiny scene,
its labels checked against the object list of its scene.json and its depth (independent geometry)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from dotsim import dataset
from dotsim.channels import rendered_channels
from dotsim.labels import MATERIAL_CLASSES, ROOM_SURFACES, SEE_THROUGH_KINDS
from dotsim.rig.geometry import Rig, pixel_grid, pixel_rays
from generator.config import ConfigError, config_from_dict, load_config
from generator.driver import generate
from generator.sample_scene import SceneResources, sample_scene_spec

pytest.importorskip("bpy")

SHARES = {"transparent_share": 0.25, "metal_share": 0.25, "ir_dark_share": 0.25}


def materials_config():
    tiny = load_config("tiny")
    return replace(tiny, render=replace(tiny.render, normals=True),
                   scene=replace(tiny.scene, object_count=(30, 30), distance=(0.5, 3.0), **SHARES))


def test_shares_are_drawn_and_without_them_scenes_stay_as_they_were():
    """The kinds come in about the shares asked for (never a transparent plane), the spec asks for the
    labels by itself; with the shares at 0 (the default) no draw is taken: the same spec as before."""
    config = replace(materials_config(), render=load_config("tiny").render)
    resources = SceneResources(pattern_path="p.png", pattern_sha256="0" * 64)
    kinds = []
    for index in range(6):
        spec = sample_scene_spec(config, index, 1, "train", resources)
        assert spec.render.labels
        objects = [o for o in spec.objects if o.name not in ROOM_SURFACES]
        assert not [o for o in objects if o.material.kind == "transparent" and o.mesh.shape == "plane"]
        kinds += [o.material.kind for o in objects]
    shares = {kind: kinds.count(kind) / len(kinds) for kind in ("transparent", "metal", "ir_dark")}
    assert all(0.12 < share < 0.38 for share in shares.values()), shares
    plain = load_config("tiny")
    spec = sample_scene_spec(plain, 0, 1, "train", resources)
    assert not spec.render.labels and {o.material.kind for o in spec.objects} == {"opaque"}
    with pytest.raises(ConfigError, match="add up to more than 1"):
        config_from_dict({"scene": {"transparent_share": 0.6, "metal_share": 0.6}})


def test_labels_follow_the_object_list_and_the_depth(tmp_path):
    """Every pixel of object k + 1 back-projects (depth, pose, rig) into the box of scene.json's
    objects[k]; the room is 0; material and transparent_or_mirror follow the object's kind; normals
    are unit vectors facing the camera; visibility is 0 on glass and metal."""
    out = tmp_path / "data"
    generate(materials_config(), out, "train", 1, seed=2, progress=False)
    scene = dataset.read_scene(out / "shard_00000" / "scene_0000000")
    meta = scene.meta
    assert meta["format_version"] == "2.2"
    assert set(meta["channels"]) == set(rendered_channels(False, ("labels", "normals")))
    rig, objects = Rig.from_dict(meta["rig"]), meta["objects"]
    kinds = [o["material"].get("kind", "opaque") for o in objects]
    assert {"transparent", "metal", "ir_dark"} <= set(kinds)
    rays = pixel_rays(*pixel_grid(rig.camera), rig.camera)
    checked = set()
    for frame, pose in zip(scene.frames, meta["poses"], strict=True):
        pose = np.asarray(pose)
        instance, depth = frame["instance"], frame["depth"].astype(np.float64)
        hit = np.isfinite(depth)
        assert (instance[~hit] == 0).all() and (instance[hit] == 0).mean() > 0.05  # the room
        world = (rays * depth[..., None])[hit] @ pose[:3, :3].T + pose[:3, 3]
        labels = instance[hit]
        for value in np.unique(labels[labels > 0]):
            obj = objects[value - 1]
            assert obj["name"] not in ROOM_SURFACES
            rotation = Rotation.from_euler("xyz", obj["rotation_euler"]).as_matrix()
            extent = np.asarray(obj["mesh"]["size"]) * np.asarray(obj["scale"])
            local = (world[labels == value] - obj["location"]) @ rotation / np.maximum(extent, 1e-9)
            # inside the unit box, to a pixel's depth rounding at the silhouette
            assert np.mean(np.abs(local).max(axis=1) <= 0.5 + 0.01 / extent.min()) > 0.99, obj["name"]
            checked.add(value)
        kind_of = np.array(["opaque"] + kinds)[instance]
        classes = np.vectorize(MATERIAL_CLASSES.index)(np.where(hit, kind_of, "none"))
        np.testing.assert_array_equal(frame["material"], classes)
        see_through = np.isin(kind_of, SEE_THROUGH_KINDS) & hit
        np.testing.assert_array_equal(frame["transparent_or_mirror"], see_through)
        assert not frame["visibility"][frame["transparent_or_mirror"].astype(bool)].any()
        normals = np.stack([frame[f"normal_{a}"].astype(np.float64) for a in "xyz"], axis=-1)
        assert np.isnan(normals[~hit]).all()
        np.testing.assert_allclose(np.linalg.norm(normals[hit], axis=-1), 1.0, atol=2e-3)
        assert np.mean((normals[hit] * rays[hit]).sum(axis=-1) < 0) > 0.99  # facing the camera
    assert len(checked) >= 5
