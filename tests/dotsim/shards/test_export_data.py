"""`dotsim export --format webdataset`, trainer.samples.Frames, and the trainer and eval on shards.

Tiny oracle datasets (dotsim/oracle_dataset.py, written with the dataset writer) are exported; the
shards are read back by dotsim.shards.reader and trainer.samples.Frames (streamed and indexed), by
the webdataset library and OpenCV (independently of dotsim's decoder), by the trainer and by eval,
and everything is compared with the folder read through dotsim.dataset.
"""

import hashlib
import json
import shutil
import tarfile

import cv2
import numpy as np
import pytest
import torch

from commands import cli
from dotsim import dataset as ds
from dotsim import file_io
from dotsim.frame_source import SourceError, open_source
from dotsim.oracle_dataset import make_dataset
from dotsim.shards import writer as export_module
from dotsim.shards.reader import decode_webdataset, index_shards, read_indexed
from dotsim.shards.writer import export_webdataset, tar_bytes_of
from tests.output_folders import assert_one_line_error, leftovers
from tests.trainer_fixtures import tiny_config
from trainer.evaluate import evaluate
from trainer.samples import Frames, SceneMeta
from trainer.train import train

SHARD_BYTES = 260_000  # a frame's sample takes about 120 kB of tar: two per shard


@pytest.fixture(scope="module")
def export(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("wds") / "train.wds"
    assert cli.main(["export", str(data), "--format", "webdataset", str(out), "--shard-size",
                     str(SHARD_BYTES)]) == 0
    return out


@pytest.fixture(scope="module")
def data10(tmp_path_factory):
    """Frames of a 10-bit sensor (the generator's default), whose IR codes float16 holds exactly."""
    return make_dataset(tmp_path_factory.mktemp("ds10"), scenes=2, frames_per_scene=2, ir_bits=10)


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
    assert set(frame) <= set(sample)
    for name, array in frame.items():
        assert sample[name].dtype == array.dtype and sample[name].shape == array.shape, name
        assert np.array_equal(sample[name], array, equal_nan=True), name


def members(path):
    with tarfile.open(path) as tar:
        return tar.getmembers()


def test_shards_sized_by_bytes_with_checksums_and_scene_json_once(export):
    index = ds.layout.load_json(export / "index.json")
    shards = index["shards"]
    assert index["format_version"] == "2.0" and index["precision"] == "exact"
    assert len(shards) == 4 and index["sample_count"] == 8 == sum(s["samples"] for s in shards)
    sums = (export / "SHA256SUMS").read_text().splitlines()
    for s, line in zip(shards, sums, strict=True):
        path = export / s["name"]
        digest = hashlib.sha256(path.read_bytes()).hexdigest()  # independently of dotsim.file_io
        assert s["sha256"] == digest and line == f"{digest}  {s['name']}"
        assert s["bytes"] == path.stat().st_size
        found = members(path)
        assert sum(512 + -(-m.size // 512) * 512 for m in found) <= SHARD_BYTES
        names = [m.name for m in found]
        assert not any(n.endswith(".disparity.npy.gz") or ".disparity." in n for n in names)  # derived
        # scene.json once per scene and shard: in the first sample of each scene the shard holds
        firsts = {}
        for n in names:
            key = n.split(".")[0]
            firsts.setdefault(key.rsplit("_frame_", 1)[0], key)
        assert sorted(n for n in names if ".scene.json" in n) == sorted(f"{k}.scene.json.gz"
                                                                         for k in firsts.values())
    assert (export / "pattern.png").read_bytes() == ds.pattern_path(ds.open_dataset(
        index["plan"]["source"]["dataset"]).root).read_bytes()
    assert tar_bytes_of([("a", b"x" * 513)]) == 512 + 1024


def test_samples_per_shard_and_shard_count(data, tmp_path, capsys):
    by_count = export_webdataset(data, tmp_path / "per3", samples_per_shard=3)
    assert [s["samples"] for s in by_count.shards] == [3, 3, 2]
    assert cli.main(["export", str(data), str(tmp_path / "four"), "--shards", "4"]) == 0
    index = ds.layout.load_json(tmp_path / "four" / "index.json")
    assert [s["samples"] for s in index["shards"]] == [2, 2, 2, 2]
    # issue 45 item 16: N shards whatever N (6 of 8 samples were 4 shards of 2), never more than samples
    six = export_webdataset(data, tmp_path / "six", shards=6)
    assert [s["samples"] for s in six.shards] == [2, 2, 1, 1, 1, 1]
    capsys.readouterr()
    assert cli.main(["export", str(data), str(tmp_path / "nine"), "--shards", "9"]) == 1
    assert_one_line_error(capsys.readouterr().err, "--shards 9", "has 8 sample(s)", "allowed: 1 to 8")
    assert not (tmp_path / "nine").exists()
    for bad in (["--shards", "0"], ["--samples-per-shard", "-1"], ["--shard-size", "1e400M"]):
        with pytest.raises(SystemExit):  # argparse: "allowed: ..."
            cli.main(["export", str(data), str(tmp_path / "bad"), *bad])
    assert cli.main(["export", str(data), str(tmp_path / "ch"), "--channels", "ir,disparity"]) == 1
    assert cli.main(["export", str(data), str(tmp_path / "ch"), "--channels", "ir,nope"]) == 1


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
        assert sample["frame.json"]["rig"] == meta["rig"]
        for name in ("depth", "projector_column", "ambient", "flood"):
            assert np.array_equal(sample[f"{name}.npy.gz"], frame[name], equal_nan=True)
        for name in ("visibility", "edge"):  # 1-bit PNGs any image reader opens
            png = cv2.imdecode(np.frombuffer(sample[f"{name}.png"], np.uint8), cv2.IMREAD_UNCHANGED)
            assert np.array_equal(png > 0, frame[name] > 0)


def test_ir_codes_as_16_bit_png_and_the_training_precision_column(data10, tmp_path):
    exact = export_webdataset(data10, tmp_path / "exact")
    training = export_webdataset(data10, tmp_path / "training", precision="training",
                                 channels=["ir", "projector_column", "visibility", "edge"])
    assert sum(s["bytes"] for s in training.shards) < 0.5 * sum(s["bytes"] for s in exact.shards)
    import webdataset as wds

    raw = list(wds.WebDataset(sorted(str(p) for p in (tmp_path / "training").glob("shard-*.tar")),
                              shardshuffle=False))
    for (key, _, frame), sample, stored in zip(folder_frames(data10), Frames(tmp_path / "training"), raw,
                                               strict=True):
        # the IR PNG holds the 10-bit codes, read back by OpenCV alone
        codes = cv2.imdecode(np.frombuffer(stored["ir.png"], np.uint8), cv2.IMREAD_UNCHANGED)
        assert codes.dtype == np.uint16
        assert np.array_equal(codes, np.round(frame["ir"].astype(np.float64) * 1023))
        assert np.array_equal(sample["ir"], frame["ir"])
        column, want = sample["projector_column"], frame["projector_column"]
        inside = np.isfinite(want) & (want > -60) & (want < 1000)
        assert np.all(np.abs(column[inside] - want[inside]) <= 1 / 32 + 1e-6)
        lit = frame["visibility"] > 0
        assert np.all(np.isfinite(column[lit]))
        # disparity derived from the stored column agrees with the folder's (from depth)
        d = sample["disparity"][lit].astype(np.float64)
        assert np.allclose(d, frame["disparity"][lit], atol=0.02), key
        assert not {"depth", "ambient", "flood"} & set(sample)


def test_export_resumes_after_a_crash_exactly_as_an_unbroken_run(data, tmp_path, monkeypatch):
    unbroken = export_webdataset(data, tmp_path / "unbroken", samples_per_shard=2)
    calls = {"n": 0}
    real = export_module.frame_files

    def crash_on_the_sixth(*args):
        calls["n"] += 1
        if calls["n"] == 6:
            raise KeyboardInterrupt  # as a kill in the middle of shard 2
        return real(*args)

    out = tmp_path / "resumed"
    monkeypatch.setattr(export_module, "frame_files", crash_on_the_sixth)
    with pytest.raises(KeyboardInterrupt):
        export_webdataset(data, out, samples_per_shard=2)
    monkeypatch.setattr(export_module, "frame_files", real)
    assert sorted(p.name for p in out.glob("shard-*.tar")) == ["shard-000000.tar", "shard-000001.tar"]
    assert not (out / "index.json").exists()
    (out / ".tmp-shard-000002.tar-99999").write_bytes(b"half a shard a kill -9 left")
    with pytest.raises(SourceError, match="not a usable dotsim dataset"):  # unfinished: no index.json
        open_source(out, "all")
    result = export_webdataset(data, out, samples_per_shard=2)
    assert result.resumed == 2 and "found done" in result.line()
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in (tmp_path / "unbroken").iterdir())
    for p in (tmp_path / "unbroken").iterdir():
        if p.name != "index.json":
            assert (out / p.name).read_bytes() == p.read_bytes(), p.name
    assert [s["sha256"] for s in unbroken.shards] == [s["sha256"] for s in result.shards]
    # a finished export: the same command does nothing, another one is refused
    assert export_webdataset(data, out, samples_per_shard=2).resumed == 4
    with pytest.raises(ds.FormatError, match="finished export of other data or options"):
        export_webdataset(data, out, samples_per_shard=3)


def test_an_unfinished_export_of_other_options_starts_over(data, tmp_path, monkeypatch, capsys):
    out = tmp_path / "x"
    real = export_module.frame_files
    calls = {"n": 0}

    def crash(*args):
        calls["n"] += 1
        if calls["n"] == 4:
            raise KeyboardInterrupt
        return real(*args)

    monkeypatch.setattr(export_module, "frame_files", crash)
    with pytest.raises(KeyboardInterrupt):
        export_webdataset(data, out, samples_per_shard=1)
    monkeypatch.setattr(export_module, "frame_files", real)
    assert len(list(out.glob("shard-*.tar"))) == 3
    result = export_webdataset(data, out, samples_per_shard=4)
    assert "starting over" in capsys.readouterr().out and result.resumed == 0
    assert [s["samples"] for s in result.shards] == [4, 4] and len(list(out.glob("shard-*.tar"))) == 2


def test_bad_sources_and_damaged_shards_are_named(data, export, tmp_path):
    with pytest.raises(ds.FormatError, match="no such shard"):
        Frames(tmp_path / "nope-{0..1}.tar")
    copy = tmp_path / "copy"
    shutil.copytree(export, copy)
    damaged = bytearray((copy / "shard-000001.tar").read_bytes())
    damaged[2000] ^= 1
    (copy / "shard-000001.tar").write_bytes(bytes(damaged))
    # by folder, by path and by brace pattern alike: the index.json beside the shards is checked
    for source in (copy, copy / "shard-000001.tar", str(copy / "shard-{000000..000003}.tar")):
        with pytest.raises(ds.FormatError, match="shard-000001.tar: sha256 differs"):
            list(Frames(source))
        with pytest.raises(SourceError, match="shard-000001.tar: sha256 differs"):
            open_source(source, "all")
    with pytest.raises(SourceError, match="no scenes with split 'val'"):
        open_source(export, "val")
    index = json.loads((copy / "index.json").read_text())
    index["format_version"] = "3.0"
    (copy / "index.json").write_text(json.dumps(index))
    with pytest.raises(ds.FormatError, match="format_version '3.0' is not supported"):
        Frames(copy)
    (tmp_path / "file").write_text("x")
    assert cli.main(["export", str(data), str(tmp_path / "file")]) == 1


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


@pytest.mark.usefixtures("one_thread")
def test_training_and_eval_from_shards_give_the_folders_figures(data, export, tmp_path):
    folder = train(tiny_config(4), open_source(data, "train"), tmp_path / "folder", progress=False)["losses"]
    shards = train(tiny_config(4), open_source(export, "train"), tmp_path / "wds", progress=False)["losses"]
    assert shards == folder and folder[0] != folder[1]
    pattern = str(export / "shard-{000000..000003}.tar")
    assert train(tiny_config(2), open_source(pattern, "train"), tmp_path / "pattern",
                 progress=False)["losses"] == folder[:2]
    # a URL (webdataset's pipe:) is copied to the cache once, then read as a local shard
    urls = [f"pipe:cat {export / f'shard-{n:06d}.tar'}" for n in range(4)]
    frames = open_source(urls, "train", cache_dir=tmp_path / "cache").frames
    assert len(frames) == 6 and len(list((tmp_path / "cache").iterdir())) == 4
    local = open_source(export, "train").frames
    for a, b in zip(frames, local, strict=True):
        assert (a.scene_index, a.frame_index) == (b.scene_index, b.frame_index)
        assert np.array_equal(a.read(("ir",))["ir"], b.read(("ir",))["ir"])
    checkpoint = tmp_path / "folder" / "checkpoint.pt"
    on_folder = evaluate(checkpoint, open_source(data, "test"), tmp_path / "e1", progress=False, images=1,
                         validation=open_source(data, "train"))
    on_shards = evaluate(checkpoint, open_source(export, "test"), tmp_path / "e2", progress=False, images=1,
                         validation=open_source(export, "train"))
    assert json.dumps(on_folder) == json.dumps(on_shards) and on_folder[0]["pixels"] > 0  # nan == nan


def test_default_collate_batches_frames_with_workers_and_their_metadata_as_a_list(data, tmp_path):
    """DataLoader(Frames(...), batch_size=N) with PyTorch's default collate: channels as tensors, keys
    and splits as lists, the scene.json dicts (which hold nulls) as a list (trainer.samples.collate_meta)."""
    out = tmp_path / "two"
    assert cli.main(["export", str(data), str(out), "--shards", "2"]) == 0
    expected = {key: (meta, frame) for key, meta, frame in folder_frames(data)}
    for source in (out, data):
        loader = torch.utils.data.DataLoader(Frames(source, channels=("ir", "depth", "visibility")),
                                             batch_size=3, num_workers=2)
        seen = []
        for batch in loader:
            assert isinstance(batch["ir"], torch.Tensor) and batch["ir"].dtype == torch.float16
            assert isinstance(batch["meta"], list) and len(batch["meta"]) == len(batch["key"]) <= 3
            for n, key in enumerate(batch["key"]):
                meta, frame = expected[key]
                assert batch["meta"][n] == meta and batch["split"][n] == meta["split"]
                assert batch["scene_index"][n].item() == meta["scene_index"]
                for name in ("ir", "depth", "visibility"):
                    assert np.array_equal(batch[name][n].numpy(), frame[name], equal_nan=True), (key, name)
                seen.append(key)
        assert sorted(seen) == sorted(expected)
    # scene.json holds nulls (a capture's poses, a rig without a second camera), which default_collate
    # cannot batch in a plain dict; a SceneMeta it keeps as a list
    with pytest.raises(TypeError):
        torch.utils.data.default_collate([{"poses": [None]}] * 2)
    assert torch.utils.data.default_collate([SceneMeta({"poses": [None]})] * 2) == [{"poses": [None]}] * 2


@pytest.mark.parametrize("precision, channels", [
    ("exact", None),
    ("training", "ir,projector_column,visibility,edge"),
])
def test_the_webdataset_library_loads_an_export_into_batches_with_two_workers(data, tmp_path, precision,
                                                                              channels):
    """An export read by the webdataset library's own pipeline and WebLoader(num_workers=2), each raw
    sample decoded alone by dotsim.shards.reader.decode_webdataset (shuffled, so a scene's
    scene.json.gz may come after its other frames), batched by webdataset, against the folder read by
    dotsim.dataset."""
    import webdataset as wds

    out = tmp_path / precision
    argv = ["export", str(data), str(out), "--shards", "2", "--precision", precision]
    assert cli.main(argv + (["--channels", channels] if channels else [])) == 0
    shards = sorted(str(p) for p in out.glob("shard-*.tar"))
    pipeline = (wds.WebDataset(shards, shardshuffle=False, nodesplitter=wds.split_by_node)
                .shuffle(8, seed=1).map(decode_webdataset).batched(3, partial=True))
    batches = list(wds.WebLoader(pipeline, batch_size=None, num_workers=2))
    expected = {key: frame for key, _, frame in folder_frames(data)}
    seen = []
    for batch in batches:  # WebLoader hands numpy arrays on as tensors
        assert "meta" not in batch and len(batch["key"]) <= 3 and isinstance(batch["ir"], torch.Tensor)
        batch = {name: value.numpy() if isinstance(value, torch.Tensor) else value
                 for name, value in batch.items()}
        for n, key in enumerate(batch["key"]):
            frame = expected[key]
            scene, _, k = key.removeprefix("scene_").partition("_frame_")
            assert (batch["scene_index"][n], batch["frame_index"][n]) == (int(scene), int(k))
            for name in ("ir", "edge"):
                assert np.array_equal(batch[name][n], frame[name]), (key, name)
            if precision == "exact":
                for name in ("depth", "projector_column", "disparity", "flood"):
                    assert np.array_equal(batch[name][n], frame[name], equal_nan=True), (key, name)
            else:  # the fixed-point column, and disparity derived from it, to their precision
                lit = frame["visibility"] > 0
                assert np.all(np.abs(batch["projector_column"][n][lit] - frame["projector_column"][lit])
                              <= 1 / 32 + 1e-6)
                assert np.allclose(batch["disparity"][n][lit], frame["disparity"][lit], atol=0.02)
                assert "depth" not in batch
            seen.append(key)
    assert sorted(seen) == sorted(expected)
    with pytest.raises(ds.FormatError, match="without __key__"):
        decode_webdataset({"ir.png": b""})


def test_a_stereo_pair_exports_its_ir_and_mask_as_png_and_derives_stereo_disparity(tmp_path):
    """ir_right as 10-bit codes and stereo_visibility as a 1-bit PNG, like their left twins;
    stereo_disparity derived on read from depth (exact export) or from the column (training export)."""
    from dotsim.channels import rendered_channels
    from dotsim.oracle_dataset import TINY_SCALE, random_depth, synthetic_frame
    from dotsim.patterns import generate_dot_pattern
    from dotsim.rig.presets import get_preset

    rig = get_preset("structure_core").scaled(TINY_SCALE)
    dots = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0)
    root = tmp_path / "stereo"
    root.mkdir()
    dots.save_png(ds.pattern_path(root))
    rng = np.random.default_rng(7)
    frames = []
    for _ in range(2):
        frame = synthetic_frame(random_depth(rig, rng), rig, dots.image.astype(np.float64), rng, ir_bits=10)
        frame["ir_right"] = np.roll(frame["ir"], -3, axis=1)
        frame["stereo_visibility"] = frame["visibility"] & (rng.uniform(size=frame["ir"].shape) > 0.2)
        frames.append(frame)
    meta = {"split": "train", "seed": 0, "rig": rig.to_dict(), "poses": [np.eye(4).tolist()] * 2,
            "pattern": {"source": dots.source, "sha256": dots.sha256, "width": rig.projector.width,
                        "height": rig.projector.height, "params": dots.params},
            "render": {"kind": "oracle (dotsim/oracle_dataset.py)"}}
    ds.write_scene(root, 0, meta, frames, channels=rendered_channels(stereo=True))
    ds.seal_dataset(root)
    exact = export_webdataset(root, tmp_path / "exact")
    training = export_webdataset(root, tmp_path / "training", precision="training", channels=[
        "ir", "ir_right", "projector_column", "visibility", "stereo_visibility"])
    names = {m.name for m in members(exact.out / exact.shards[0]["name"])}
    assert {"scene_0000000_frame_0.ir_right.png", "scene_0000000_frame_0.stereo_visibility.png"} <= names
    folder = [f for _, _, f in folder_frames(root)]
    for sample, frame in zip(Frames(exact.out), folder, strict=True):
        assert_same_frame(sample, sample["meta"], frame)
        assert "stereo_disparity" in sample
    for sample, frame in zip(Frames(training.out), folder, strict=True):
        assert np.array_equal(sample["ir_right"], frame["ir_right"])
        seen = frame["stereo_visibility"] > 0
        assert np.allclose(sample["stereo_disparity"][seen], frame["stereo_disparity"][seen], atol=0.02)


def test_unusable_output_folders_are_one_line_and_a_full_disk_resumes(data, tmp_path, read_only_folder,
                                                                       monkeypatch, capsys):
    assert cli.main(["export", str(data), "-o", str(read_only_folder / "wds")]) == 1
    assert_one_line_error(capsys.readouterr().err, read_only_folder / "wds", "not writable")
    with pytest.raises(SystemExit):
        cli.main(["export", str(data), "-o", str(tmp_path / "x"), "--shard-size", "1e400M"])
    assert "'1e400M': allowed: bytes, or a number with K, M or G" in capsys.readouterr().err
    out = tmp_path / "full"
    real, calls = file_io.os.fsync, {"n": 0}

    def full_after_two(fd):  # two shards reach the disk, then it is full
        calls["n"] += 1
        if calls["n"] > 4:  # each shard: the shard, then .progress.json
            raise OSError(28, "No space left on device")
        return real(fd)

    monkeypatch.setattr(file_io.os, "fsync", full_after_two)
    assert cli.main(["export", str(data), "-o", str(out), "--samples-per-shard", "2"]) == 1
    assert_one_line_error(capsys.readouterr().err, "no space left on device")
    assert not leftovers(out) and len(list(out.glob("shard-*.tar"))) == 2
    monkeypatch.setattr(file_io.os, "fsync", real)  # space freed: the same command finishes the export
    assert cli.main(["export", str(data), "-o", str(out), "--samples-per-shard", "2"]) == 0
    assert "2 found done by an earlier run" in capsys.readouterr().out
    unbroken = export_webdataset(data, tmp_path / "unbroken", samples_per_shard=2)
    assert [s["sha256"] for s in unbroken.shards] == [
        s["sha256"] for s in ds.layout.load_json(out / "index.json")["shards"]]
