"""Asset cache build: reproducible, incremental, resumable; user folders with bad inputs are skipped
with a report line; the loader's errors say what to run. Small manifests only (a few assets)."""

import argparse
import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import trimesh

from assets_manifest import cli
from assets_manifest.cache import AssetCacheError, build_asset_cache, load_asset_cache
from assets_manifest.manifest import load_manifest
from assets_manifest.mesh_arrays import load_mesh_npz
from tests.output_folders import assert_one_line_error, leftovers

SMALL = """
[split]
name = "{split}"
clutter_density = {density}

[[meshes]]
name = "blob"
generator = "noise_displaced_sphere"
seeds = [0, 2]
params = {{ subdivisions = 2 }}
scale = [0.05, 0.3]
license = "CC0-1.0"

[[meshes]]
name = "seat"
generator = "furniture"
seeds = [0, 1]
scale = [0.4, 1.0]
license = "CC0-1.0"

[[textures]]
name = "noise"
generator = "fractal_noise"
seeds = [0, 2]
params = {{ size = 64, octaves = 3 }}
scale = [0.1, 1.0]
license = "CC0-1.0"

[[textures]]
name = "photo"
skimage = ["brick"]
scale = [0.2, 1.0]
"""


def write_manifest(folder: Path, text: str, split: str = "train", density: float = 1.0) -> Path:
    path = folder / f"{split}.toml"
    path.write_text(text.format(split=split, density=density))
    return path


def build(manifest_path: Path, cache: Path, lines: list | None = None, workers: int = 1):
    log = lines.append if lines is not None else (lambda line: None)
    return build_asset_cache(load_manifest(manifest_path), cache, workers=workers, progress=False, log=log)


def checksums(cache: Path, split: str = "train") -> dict[str, tuple[str, str]]:
    index = json.loads((cache / split / "index.json").read_text())
    return {e["id"]: (e["sha256"], e["content_sha256"]) for e in index["meshes"] + index["textures"]}


def test_same_manifest_gives_same_checksums_and_bytes(tmp_path):
    manifest = write_manifest(tmp_path, SMALL)
    build(manifest, tmp_path / "a")
    build(manifest, tmp_path / "b", workers=2)  # parallel workers must not change anything
    first, second = checksums(tmp_path / "a"), checksums(tmp_path / "b")
    assert set(first) == {"blob_0000", "blob_0001", "seat_0000", "noise_0000", "noise_0001", "photo_brick"}
    assert first == second
    for asset_id in first:
        folder = "meshes" if asset_id in ("blob_0000", "blob_0001", "seat_0000") else "textures"
        suffix = ".npz" if folder == "meshes" else ".png"
        a = (tmp_path / "a" / "train" / folder / f"{asset_id}{suffix}").read_bytes()
        assert a == (tmp_path / "b" / "train" / folder / f"{asset_id}{suffix}").read_bytes()
    # Different seeds give different assets.
    assert first["blob_0000"][1] != first["blob_0001"][1]


def test_second_build_reuses_and_a_changed_entry_rebuilds_only_itself(tmp_path):
    manifest = write_manifest(tmp_path, SMALL)
    cache = tmp_path / "cache"
    summary = build(manifest, cache)
    assert len(summary.built) == 6 and not summary.reused
    before = checksums(cache)
    again = build(manifest, cache)
    assert again.built == [] and len(again.reused) == 6
    changed_text = SMALL.replace("octaves = 3", "octaves = 4")
    write_manifest(tmp_path, changed_text)
    changed = build(manifest, cache)
    assert sorted(changed.built) == ["noise_0000", "noise_0001"] and len(changed.reused) == 4
    after = checksums(cache)
    assert all(after[i] == before[i] for i in after if not i.startswith("noise"))
    assert all(after[i] != before[i] for i in ("noise_0000", "noise_0001"))
    # Dropping an entry removes its file.
    write_manifest(tmp_path, changed_text.replace('skimage = ["brick"]', 'skimage = ["gravel"]'))
    dropped = build(manifest, cache)
    assert dropped.removed == ["photo_brick"] and dropped.built == ["photo_gravel"]
    assert not (cache / "train" / "textures" / "photo_brick.png").exists()


def test_interrupted_build_is_refused_then_resumed(tmp_path):
    manifest = write_manifest(tmp_path, SMALL)
    cache = tmp_path / "cache"
    build(manifest, cache)
    index_path = cache / "train" / "index.json"
    index = json.loads(index_path.read_text())
    index["complete"] = False
    index_path.write_text(json.dumps(index))
    (cache / "train" / "meshes" / "seat_0000.npz").unlink()
    leftover = cache / "train" / "meshes" / ".tmp-seat_0000.npz-123"  # atomic_write_bytes naming
    leftover.write_bytes(b"half-written")
    with pytest.raises(AssetCacheError, match=r"interrupted build.*dotsim assets build --split train"):
        load_asset_cache(cache, "train")
    resumed = build(manifest, cache)
    assert resumed.built == ["seat_0000"] and len(resumed.reused) == 5
    assert not leftover.exists()
    assert len(load_asset_cache(cache, "train").meshes) == 3


def test_loader_gives_entries_and_clear_errors(tmp_path):
    cache = tmp_path / "cache"
    with pytest.raises(
        AssetCacheError, match=r"no asset cache index at .*index.json.*assets build --split test"
    ):
        load_asset_cache(cache, "test")
    build(write_manifest(tmp_path, SMALL, split="test", density=1.7), cache)
    loaded = load_asset_cache(cache, "test", verify=True)
    assert loaded.clutter_density == 1.7 and loaded.index["clutter_density"] == 1.7
    assert [e.id for e in loaded.meshes] == ["blob_0000", "blob_0001", "seat_0000"]
    seat = loaded.meshes[2]
    assert Path(seat.path).is_absolute() and seat.scale_hint == (0.4, 1.0) and seat.license == "CC0-1.0"
    photo = loaded.textures[-1]
    assert photo.license.startswith("CC0-1.0") and cv2.imread(photo.path, cv2.IMREAD_UNCHANGED).ndim == 2
    noise = cv2.imread(loaded.textures[0].path, cv2.IMREAD_UNCHANGED)
    assert noise.dtype == np.uint16 and noise.shape == (64, 64)
    Path(seat.path).write_bytes(b"corrupted")
    with pytest.raises(AssetCacheError, match=r"seat_0000.npz does not match its sha256"):
        load_asset_cache(cache, "test", verify=True)
    Path(seat.path).unlink()
    with pytest.raises(AssetCacheError, match=r"seat_0000.npz listed in .* is missing"):
        load_asset_cache(cache, "test")
    (cache / "test" / "index.json").write_text("{not json")
    with pytest.raises(AssetCacheError, match="unreadable"):
        load_asset_cache(cache, "test")


def _user_folders(root: Path) -> tuple[Path, Path]:
    meshes, images = root / "meshes", root / "images"
    meshes.mkdir()
    images.mkdir()
    trimesh.creation.box((1.0, 2.0, 0.5)).export(meshes / "good_box.stl")
    (meshes / "good_cube_uv.obj").write_text(
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\n"
        "f 1/1 4/4 3/3\nf 1/1 3/3 2/2\nf 5/1 6/2 7/3\nf 5/1 7/3 8/4\nf 1/1 2/2 6/3\nf 1/1 6/3 5/4\n"
        "f 2/1 3/2 7/3\nf 2/1 7/3 6/4\nf 3/1 4/2 8/3\nf 3/1 8/3 7/4\nf 4/1 1/2 5/3\nf 4/1 5/3 8/4\n"
    )
    (meshes / "garbage.ply").write_bytes(b"ply\nformat nonsense\n\x00\x01\x02 not a mesh")
    (meshes / "zero_bytes.stl").write_bytes(b"")
    (meshes / "points_only.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    (meshes / "collinear.obj").write_text("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n")
    gradient = np.tile(np.linspace(0, 65535, 32).astype(np.uint16), (24, 1))
    cv2.imwrite(str(images / "good16.png"), gradient)
    cv2.imwrite(
        str(images / "good_rgb.jpg"), np.random.default_rng(0).integers(0, 255, (20, 30, 3), np.uint8)
    )
    (images / "garbage.png").write_bytes(b"\x89PNG\r\n\x1a\n but then nothing sensible")
    cv2.imwrite(str(images / "constant.png"), np.full((16, 16), 77, np.uint8))
    cv2.imwrite(str(images / "tiny.png"), np.arange(16, dtype=np.uint8).reshape(4, 4))
    return meshes, images


def test_user_folders_skip_each_bad_input_with_a_report_line(tmp_path):
    meshes, images = _user_folders(tmp_path)
    manifest = tmp_path / "train.toml"
    manifest.write_text(
        '[split]\nname = "train"\n'
        '[[meshes]]\nname = "mine"\nfolder = "meshes"\nscale = [0.1, 1.0]\nlicense = "own"\n'
        '[[textures]]\nname = "pics"\nfolder = "images"\nscale = [0.1, 1.0]\nlicense = "own"\n'
    )
    lines = []
    summary = build(manifest, tmp_path / "cache", lines)
    assert sorted(summary.built) == ["mine_good_box", "mine_good_cube_uv", "pics_good16", "pics_good_rgb"]
    expected = {
        "garbage.ply": "cannot read as a mesh",
        "zero_bytes.stl": r"empty file \(0 bytes\)",
        "points_only.obj": "no triangle mesh|empty mesh",
        "collinear.obj": "degenerate mesh: all 1 triangles have zero area",
        "garbage.png": "cannot read as an image",
        "constant.png": "constant image: every pixel is 77",
        "tiny.png": "too small: 4x4 px",
    }
    report = lines[:-1]
    assert len(report) == len(expected) == len(summary.skipped)
    for name, reason in expected.items():
        matching = [line for line in report if f"/{name}" in line]
        assert len(matching) == 1, name
        assert re.search(reason, matching[0]), matching[0]
    assert lines[-1] == summary.line() and "4 built" in lines[-1] and "7 skipped" in lines[-1]
    cache = load_asset_cache(tmp_path / "cache", "train")
    assert [s["id"] for s in cache.index["skipped"]] == [s["id"] for s in summary.skipped]
    # The STL box keeps its proportions; the OBJ cube keeps its own UVs (in [0,1]).
    box = load_mesh_npz(cache.meshes[0].path)
    assert np.allclose(np.ptp(box["vertices"], axis=0), [0.5, 1.0, 0.25], atol=1e-6)
    cube = load_mesh_npz(cache.meshes[1].path)
    assert {tuple(uv) for uv in cube["uvs"].round(6)} <= {(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0)}
    grey16 = cv2.imread(cache.textures[0].path, cv2.IMREAD_UNCHANGED)
    assert grey16.dtype == np.uint16 and np.array_equal(
        grey16[0], np.linspace(0, 65535, 32).astype(np.uint16)
    )


def test_cli_build_and_check(tmp_path, capsys):
    parser = argparse.ArgumentParser(prog="dotsim")
    cli.add_parser(parser.add_subparsers())
    train = write_manifest(tmp_path, SMALL)
    test_text = SMALL.replace("seeds = [0, 2]", "seeds = [7, 9]").replace('"brick"', '"grass"')
    test = write_manifest(tmp_path, test_text.replace("seeds = [0, 1]", "seeds = [3, 4]"), split="test")
    cache = str(tmp_path / "cache")

    def run(*argv):
        args = parser.parse_args(list(argv))
        return args.func(args)

    assert (
        run(
            "assets", "build", "--split", "train", "--manifest", str(train), "--cache", cache, "--no-progress"
        )
        == 0
    )
    assert (
        run("assets", "build", "--split", "test", "--manifest", str(test), "--cache", cache, "--no-progress")
        == 0
    )
    check = (
        "assets",
        "check",
        "--cache",
        cache,
        "--train-manifest",
        str(train),
        "--test-manifest",
        str(test),
    )
    assert run(*check) == 0
    assert "0 problem(s)" in capsys.readouterr().out
    sheet = tmp_path / "sheet.png"
    assert run("assets", "preview", "--split", "train", "--cache", cache, "-o", str(sheet)) == 0
    # 3 meshes + 3 textures of 128 px with 2 px gutters, 8 columns: one row.
    assert cv2.imread(str(sheet), cv2.IMREAD_UNCHANGED).shape == (132, 8 * 130 + 2)
    # The shipped manifests differ from the ones this cache was built from: reported.
    assert run("assets", "check", "--cache", cache) == 1
    assert "built from another manifest" in capsys.readouterr().out
    # A manifest that declares another split is refused.
    assert run("assets", "build", "--split", "test", "--manifest", str(train), "--cache", cache) == 2
    assert "declares split 'train', not 'test'" in capsys.readouterr().err


def test_cli_build_into_a_read_only_or_full_cache_is_one_line(tmp_path, read_only_folder, no_space, capsys):
    """(issue 37, item 1) A read-only --cache is refused before anything is built; a full one stops
    at the first file, naming it, with nothing half-written."""
    from commands.cli import main

    manifest = write_manifest(tmp_path, SMALL)
    argv = ["assets", "build", "--split", "train", "--manifest", str(manifest), "--no-progress", "--cache"]
    assert main([*argv, str(read_only_folder / "cache")]) == 1
    assert_one_line_error(capsys.readouterr().err, f"--cache {read_only_folder / 'cache'}", "not writable")
    assert not any(read_only_folder.iterdir())
    assert main([*argv, str(tmp_path / "cache"), "--workers", "1"]) == 1  # (no_space: in this process)
    assert_one_line_error(capsys.readouterr().err, tmp_path / "cache", "no space left on device")
    assert not leftovers(tmp_path)
