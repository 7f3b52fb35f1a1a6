"""`dotsim export --format webdataset`, dotsim.data.Frames and the trainer's --data on shards.

A tiny oracle dataset (tests/trainer_fixtures.py, written with the dataset writer) is exported; the
shards are read back by dotsim.data (streamed and indexed), by the webdataset library itself, and
by the trainer, and everything is compared with the folder read through dotsim.dataset.
"""

import hashlib
import tarfile

import numpy as np
import pytest
import torch

from commands import cli
from commands.export import export_webdataset, tar_bytes_of
from dotsim import dataset as ds
from dotsim.data import Frames, index_shards, read_indexed
from tests.trainer_fixtures import tiny_config
from trainer.data import DataError, list_frames
from trainer.train import train

SHARD_BYTES = 600_000  # a frame's sample takes about 250 KB of tar: two per shard


@pytest.fixture(scope="module")
def export(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("wds") / "train.wds"
    assert cli.main(["export", str(data), "--format", "webdataset", str(out), "--shard-size",
                     str(SHARD_BYTES)]) == 0
    return out


def folder_frames(data):
    """(key, scene meta, frame) of every frame of the folder, through dotsim.dataset's reader."""
    opened = ds.open_dataset(data)
    out = []
    for ref in opened.scenes:
        meta = ds.read_scene_meta(ref.path)
        for k, path in enumerate(ref.frame_paths):
            out.append((f"scene_{ref.scene_index:07d}_frame_{k}", meta, ds.read_frame(path)))
    return out


def assert_same_frame(sample, meta, frame):
    assert sample["meta"] == meta
    for name, array in frame.items():
        assert sample[name].dtype == array.dtype and sample[name].shape == array.shape, name
        assert np.array_equal(sample[name], array, equal_nan=True), name


def test_shards_sized_by_bytes_with_checksums(export):
    index = ds.layout.load_json(export / "index.json")
    shards = index["shards"]
    assert len(shards) == 4 and index["sample_count"] == 8 == sum(s["samples"] for s in shards)
    sums = (export / "SHA256SUMS").read_text().splitlines()
    for s, line in zip(shards, sums, strict=True):
        path = export / s["name"]
        digest = hashlib.sha256(path.read_bytes()).hexdigest()  # independently of dotsim.file_io
        assert s["sha256"] == digest and line == f"{digest}  {s['name']}"
        assert s["bytes"] == path.stat().st_size
        with tarfile.open(path) as tar:
            members = tar.getmembers()
        used = sum(512 + -(-m.size // 512) * 512 for m in members)
        assert used <= SHARD_BYTES and len(members) == s["samples"] * 10  # 8 channels + 2 JSON
    assert tar_bytes_of([("a", b"x" * 513)]) == 512 + 1024


def test_round_trip_is_exact_streamed_indexed_and_by_the_webdataset_library(data, export):
    expected = folder_frames(data)
    streamed = list(Frames(export))
    assert [s["key"] for s in streamed] == [k for k, _, _ in expected]
    for sample, (_, meta, frame) in zip(streamed, expected, strict=True):
        assert_same_frame(sample, meta, frame)
    for sample, (_, meta, frame) in zip(Frames(data), expected, strict=True):  # the folder form
        assert_same_frame(sample, meta, frame)
    indexed = index_shards(export)
    for located, (key, meta, frame) in zip(indexed, expected, strict=True):
        sample = read_indexed(located)
        assert sample["key"] == key
        assert_same_frame(sample, meta, frame)

    import webdataset as wds

    shards = sorted(str(p) for p in export.glob("shard-*.tar"))
    by_library = list(wds.WebDataset(shards, shardshuffle=False).decode())
    assert [s["__key__"] for s in by_library] == [k for k, _, _ in expected]
    for sample, (_, meta, frame) in zip(by_library, expected, strict=True):
        assert sample["scene.json"] == meta
        for name, array in frame.items():
            assert np.array_equal(sample[f"{name}.npy"], array, equal_nan=True)


def test_rank_and_worker_splitting_covers_every_frame_once(data, export):
    every = [k for k, _, _ in folder_frames(data)]
    for source in (export, data):
        parts = [[s["key"] for s in Frames(source, channels=("ir",), rank=r, world=2)] for r in range(2)]
        assert sorted(parts[0] + parts[1]) == sorted(every) and not set(parts[0]) & set(parts[1])
        assert parts[0] and parts[1]
    loader = torch.utils.data.DataLoader(Frames(export, channels=("depth",), split="train"), batch_size=None,
                                         num_workers=2, collate_fn=lambda s: s["key"])
    keys = list(loader)
    assert sorted(keys) == sorted(k for k in every if not k.startswith("scene_0000003"))  # 3 is test
    assert len(keys) == len(set(keys)) == 6


def test_bad_sources_and_damaged_shards_are_named(data, export, tmp_path):
    with pytest.raises(ds.FormatError, match="already holds an export"):
        export_webdataset(data, export)
    with pytest.raises(ds.FormatError, match="no such shard"):
        Frames(tmp_path / "nope-{0..1}.tar")
    copy = tmp_path / "copy"
    copy.mkdir()
    for p in export.iterdir():
        (copy / p.name).write_bytes(p.read_bytes())
    damaged = bytearray((copy / "shard-000001.tar").read_bytes())
    damaged[2000] ^= 1
    (copy / "shard-000001.tar").write_bytes(bytes(damaged))
    with pytest.raises(ds.FormatError, match="shard-000001.tar: sha256 differs"):
        list(Frames(copy))
    with pytest.raises(DataError, match="no scenes with split 'val'"):
        list_frames(export, "val")


@pytest.mark.usefixtures("one_thread")
def test_training_from_shards_gives_the_folders_losses(data, export, tmp_path):
    folder = train(tiny_config(4), data, tmp_path / "folder", progress=False)["losses"]
    shards = train(tiny_config(4), export, tmp_path / "wds", progress=False)["losses"]
    assert shards == folder and folder[0] != folder[1]
    pattern = str(export / "shard-{000000..000003}.tar")
    assert train(tiny_config(2), pattern, tmp_path / "pattern", progress=False)["losses"] == folder[:2]
    # a URL (webdataset's pipe:) is copied to the cache once, then read as a local shard
    urls = [f"pipe:cat {export / f'shard-{n:06d}.tar'}" for n in range(4)]
    frames, rig, _ = list_frames(urls, "train", cache_dir=tmp_path / "cache")
    assert len(frames) == 6 and len(list((tmp_path / "cache").iterdir())) == 4
    local, _, _ = list_frames(export, "train")
    for a, b in zip(frames, local, strict=True):
        assert (a.scene_index, a.frame_index) == (b.scene_index, b.frame_index)
        assert np.array_equal(a.read(("ir",))["ir"], b.read(("ir",))["ir"])
