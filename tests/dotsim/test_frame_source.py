"""dotsim.frame_source: one data source, opened once, handing out frames, rig and pattern, from a
dataset folder and from its export alike (real datasets written with the dataset writer, real shards)."""

from __future__ import annotations

import doctest
import json

import numpy as np
import pytest

from dotsim import frame_source
from dotsim.dataset import open_dataset, read_frame
from dotsim.frame_source import SourceError, open_source
from dotsim.oracle_dataset import make_dataset
from dotsim.patterns import load_pattern
from dotsim.rig.geometry import Rig
from dotsim.shards.writer import export_webdataset


def test_doctests():
    assert doctest.testmod(frame_source).failed == 0


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    return make_dataset(tmp_path_factory.mktemp("source") / "data", 2, frames_per_scene=2, test_scenes=1)


def test_a_folder_and_its_export_give_the_same_frames_rig_and_pattern(data, tmp_path):
    folder = open_source(data, "train")
    scenes = [s for s in open_dataset(data).scenes if s.split == "train"]
    assert [(f.scene_index, f.frame_index) for f in folder.frames] == [
        (s.scene_index, k) for s in scenes for k in range(s.frame_count)]
    scene = json.loads((scenes[0].path / "scene.json").read_text())
    assert folder.rig == Rig.from_dict(scene["rig"]) and (folder.name, folder.split) == (str(data), "train")
    np.testing.assert_array_equal(folder.pattern, load_pattern(data / "pattern.png").image)
    assert folder.pattern is folder.pattern and folder.first(1).pattern is folder.pattern  # read once
    assert "disparity" not in folder.channels and "ir" in folder.channels and not folder.stereo

    export = open_source(export_webdataset(data, tmp_path / "wds").out, "train")
    assert [(f.scene_index, f.frame_index) for f in export.frames] == [
        (f.scene_index, f.frame_index) for f in folder.frames]
    assert export.rig == folder.rig and export.channels == folder.channels
    np.testing.assert_array_equal(export.pattern, folder.pattern)
    for a, b in zip(folder.frames, export.frames, strict=True):
        want = read_frame(a.path, channels=("ir", "disparity"))
        got = b.read(("ir", "disparity"))
        for name in want:
            np.testing.assert_array_equal(got[name], want[name])


def test_a_stereo_pair_is_found_in_the_channel_registry(tmp_path):
    pair = open_source(make_dataset(tmp_path / "pair", 1, frames_per_scene=1, pair=True), "all")
    assert pair.stereo and "ir_right" in pair.channels


def test_splits_and_held_out_frames(data):
    with pytest.raises(SourceError, match=r"no scenes with split 'val' \(splits present: .*'train': 2"):
        open_source(data, "val")
    train, test = open_source(data, "train"), open_source(data, "test")
    assert test.held_out(0, train, "training") == test.frames
    assert len(train.held_out(2, test, "evaluated")) == 2
    with pytest.raises(SourceError, match="validation frames \\(split 'all'\\) overlap the training frames"):
        open_source(data, "all").held_out(1, train, "training")
    with pytest.raises(SourceError, match="not a usable dotsim dataset"):
        open_source(data / "missing", "all")
