"""Manifests: validation errors name the field; the shipped splits are large and disjoint; the
disjointness check fails on a shared source spec, a shared user file, and a shared built result."""

import hashlib
import shutil
import textwrap

import numpy as np
import pytest

from assets_manifest.cache import build_asset_cache, default_manifest_path, load_asset_cache
from assets_manifest.manifest import ManifestError, check_disjoint, find_overlaps, load_manifest
from assets_manifest.package_images import SKIMAGE_PHOTOS, skimage_image_path
from assets_manifest.params import sample_params
from assets_manifest.procedural_textures import TEXTURE_FAMILIES, bricks, checker, grating


def manifest(tmp_path, split: str, body: str):
    path = tmp_path / f"{split}.toml"
    path.write_text(f'[split]\nname = "{split}"\n' + textwrap.dedent(body))
    return load_manifest(path)


def mesh_entry(name, generator, seeds, params="{}"):
    return f"""
    [[meshes]]
    name = "{name}"
    generator = "{generator}"
    seeds = {seeds}
    params = {params}
    scale = [0.1, 0.5]
    license = "CC0-1.0"
    """


def test_shipped_manifests_are_large_valid_and_disjoint():
    train, test = load_manifest(default_manifest_path("train")), load_manifest(default_manifest_path("test"))
    assert (train.split, test.split) == ("train", "test")
    for m in (train, test):
        assert len(m.meshes) >= 300 and len(m.textures) >= 150
        assert len({s.source_key for s in m.assets}) == len(m.assets)
        families = {s.source.get("generator") for s in m.meshes}
        assert len(families) >= 8
    assert train.clutter_density != test.clutter_density
    check_disjoint(train, test)
    # Every listed photograph is in the installed wheel, and the two splits use different ones.
    photos = [{s.source["skimage"] for s in m.textures if "skimage" in s.source} for m in (train, test)]
    assert photos[0] and photos[1] and not photos[0] & photos[1]
    assert all(skimage_image_path(n).is_file() for n in SKIMAGE_PHOTOS)


def test_same_source_spec_in_both_splits_fails(tmp_path):
    params = "{ amplitude = [0.1, 0.2] }"
    a = manifest(tmp_path, "train", mesh_entry("blob", "noise_displaced_sphere", "[0, 10]", params))
    # Same family, params and seeds 5..14 under another name: seeds 5..9 are shared.
    b = manifest(tmp_path, "test", mesh_entry("rock", "noise_displaced_sphere", "[5, 15]", params))
    overlaps = find_overlaps(a, b)
    assert len(overlaps) == len(set(range(0, 10)) & set(range(5, 15)))
    assert "train blob_0005 and test rock_0005" in overlaps[0]
    with pytest.raises(ManifestError, match="share 5 asset"):
        check_disjoint(a, b)
    # Other params with the same seeds are other assets.
    c = manifest(
        tmp_path, "test", mesh_entry("rock", "noise_displaced_sphere", "[5, 15]", "{ amplitude = 0.3 }")
    )
    check_disjoint(a, c)


def test_same_user_file_in_both_splits_fails(tmp_path):
    for split in ("train", "test"):
        (tmp_path / split).mkdir()
    shutil.copy(skimage_image_path("camera"), tmp_path / "train" / "cam.png")
    shutil.copy(skimage_image_path("camera"), tmp_path / "test" / "other_name.png")
    shutil.copy(skimage_image_path("coins"), tmp_path / "test" / "coins.png")

    def folder(split):
        return f"""
        [[textures]]
        name = "pics"
        folder = "{split}"
        scale = [0.1, 1.0]
        license = "CC0-1.0"
        """

    a, b = manifest(tmp_path, "train", folder("train")), manifest(tmp_path, "test", folder("test"))
    overlaps = find_overlaps(a, b)
    assert len(overlaps) == 1 and "pics_cam" in overlaps[0] and "pics_other_name" in overlaps[0]


def test_same_built_mesh_from_different_specs_fails(tmp_path):
    # Fixed box sizes make every seed the same mesh: the specs differ (seed), the results do not.
    fixed = "{ size_x = 0.3, size_y = 0.5, size_z = 0.2 }"
    a = manifest(tmp_path, "train", mesh_entry("crate", "box", "[0, 1]", fixed))
    b = manifest(tmp_path, "test", mesh_entry("crate", "box", "[1, 2]", fixed))
    assert find_overlaps(a, b) == []
    cache = tmp_path / "cache"
    for m in (a, b):
        build_asset_cache(m, cache, progress=False, log=lambda line: None)
    index_a, index_b = load_asset_cache(cache, "train").index, load_asset_cache(cache, "test").index
    overlaps = find_overlaps(a, b, index_a, index_b)
    assert len(overlaps) == 1 and "same content: train crate_0000 and test crate_0001" in overlaps[0]
    with pytest.raises(ManifestError, match="same content"):
        check_disjoint(a, b, index_a, index_b)


@pytest.mark.parametrize(
    "body, message",
    [
        (mesh_entry("x", "pyramid", "[0, 2]"), "unknown mesh generator 'pyramid'; known: .*box"),
        (mesh_entry("x", "box", "[3, 2]"), r"'seeds' must be \[first, stop\)"),
        (mesh_entry("x", "box", "[0, 2]", "{ size_q = 1 }"), "unknown parameter 'size_q'; allowed: size_x"),
        (mesh_entry("x", "box", "[0, 2]", "{ size_x = [2.0, 1.0] }"), r"range \[2.0, 1.0\] has lo > hi"),
        (mesh_entry("x", "box", "[0, 2]", '{ size_x = "big" }'), "must be a number or"),
        (mesh_entry("x", "furniture", "[0, 2]", '{ kind = ["sofa"] }'), "allowed: one or a list of"),
        (mesh_entry("x", "box", "[0, 2]").replace('license = "CC0-1.0"', ""), "'license'"),
        (
            mesh_entry("x", "box", "[0, 2]").replace("scale = [0.1, 0.5]", "scale = [0.5, 0.1]"),
            "'scale' must be",
        ),
        (mesh_entry("x", "box", "[0, 1]") + mesh_entry("x", "box", "[0, 1]"), "asset ids appear twice"),
        (
            '[[textures]]\nname = "p"\nskimage = ["lena"]\nscale = [1, 2]\n',
            "unknown scikit-image photograph 'lena'",
        ),
        (
            '[[meshes]]\nname = "m"\nfolder = "nowhere"\nscale = [1, 2]\nlicense = "x"\n',
            "folder .*nowhere.* does not",
        ),
        ('[[meshes]]\nname = "m"\ncolour = 1\n', r"unknown field\(s\) \['colour'\]"),
    ],
)
def test_invalid_manifests_name_the_problem(tmp_path, body, message):
    with pytest.raises(ManifestError, match=message) as info:
        manifest(tmp_path, "train", body)
    assert "train.toml" in str(info.value)


def test_pinned_checksum_is_verified(tmp_path):
    shutil.copy(skimage_image_path("coins"), tmp_path / "coins.png")
    body = '[[textures]]\nname = "c"\nfile = "coins.png"\nsha256 = "{}"\nscale = [1, 2]\nlicense = "x"\n'
    with pytest.raises(ManifestError, match="coins.png has sha256 .* the manifest pins 00ab"):
        manifest(tmp_path, "train", body.format("00ab"))
    digest = hashlib.sha256((tmp_path / "coins.png").read_bytes()).hexdigest()
    assert len(manifest(tmp_path, "train", body.format(digest)).textures) == 1


def test_texture_patterns_match_their_definitions():
    size, period = 64, 8
    rows, cols = np.mgrid[0:size, 0:size]
    assert np.array_equal(checker(size, period, 0.0), ((rows // period + cols // period) % 2).astype(float))
    stripes = grating(size, period, 0.0, square=False)
    assert np.allclose(stripes, 0.5 + 0.5 * np.sin(2 * np.pi * cols / period))
    wall = bricks(np.random.default_rng(0), size, 16.0, 8.0, 2.0, 0.0)
    assert (wall[rows % 8 < 2] == 0).all() and (
        wall[(rows % 8 >= 2) & (cols % 16 >= 2) & (rows // 8 % 2 == 0)] == 1
    ).all()
    for name, family in TEXTURE_FAMILIES.items():
        rng = np.random.default_rng(1)
        params = sample_params({"size": 32, "mean": 0.5, "contrast": 0.6}, family.defaults, rng)
        image = family.make(params, rng)
        assert image.shape == (32, 32), name
        # mean +- contrast/2 with the pattern stretched to full range: exactly [0.2, 0.8].
        assert np.isclose(image.min(), 0.2) and np.isclose(image.max(), 0.8), name
