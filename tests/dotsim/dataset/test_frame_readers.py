"""Frames in the common readers' hands (issue 36, item 1): every compression a dataset's frames may have
([output] exr_compression) read back by the OpenEXR package and dotsim; what OpenCV and imageio make of
them (nothing, as docs/FORMAT.md "Compression" says); and the README's three-line snippets per tool run
on a real frame and a real export's members."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tarfile
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from commands import cli
from dotsim import dataset as ds
from dotsim.oracle_dataset import make_dataset

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def frame_path(tmp_path_factory):
    """frame_0 of a one-scene dataset of a 10-bit sensor (the generator's default bit depth)."""
    data = make_dataset(tmp_path_factory.mktemp("readers"), scenes=1, frames_per_scene=1, ir_bits=10)
    return ds.open_dataset(data).scenes[0].frame_paths[0]


def rewritten(frame_path: Path, compression: str, folder: Path) -> Path:
    """The frame written again by dotsim's frame writer with another compression (EXR_COMPRESSIONS key)."""
    meta = ds.read_scene_meta(frame_path.parent)
    path = folder / f"{compression}.exr"
    ds.write_frame_file(path, ds.read_frame(frame_path), ds.camera_size(meta),
                        channels=tuple(meta["channels"]), compression=ds.EXR_COMPRESSIONS[compression],
                        rig=meta["rig"])
    return path


@pytest.mark.parametrize("compression", list(ds.EXR_COMPRESSIONS))
def test_every_compression_is_read_back_bit_for_bit_by_openexr_and_dotsim(frame_path, tmp_path, compression):
    path = rewritten(frame_path, compression, tmp_path)
    original = ds.read_frame(frame_path)
    exr = OpenEXR.File(str(path), separate_channels=True)  # the OpenEXR package alone
    assert exr.header()["compression"] == getattr(OpenEXR, ds.EXR_COMPRESSIONS[compression])
    stored = exr.channels()
    assert set(stored) == set(original) - {"disparity"}  # derived on read, never stored
    for name, channel in stored.items():
        want = original[name].astype(np.uint32) if name in ds.MASK_CHANNELS else original[name]
        assert channel.pixels.dtype == want.dtype, name
        assert np.array_equal(channel.pixels, want, equal_nan=True), name
    again = ds.read_frame(path)
    for name, array in original.items():
        assert np.array_equal(again[name], array, equal_nan=True), name


READERS = """
import json, sys, warnings
import cv2, imageio.v3 as iio
found = {}
for path in sys.argv[1:]:
    image = cv2.imread(path, cv2.IMREAD_UNCHANGED)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            other = iio.imread(path)
        other = [str(other.dtype), list(other.shape)]
    except Exception as error:
        other = type(error).__name__
    found[path] = [None if image is None else [str(image.dtype), list(image.shape)], other]
print(json.dumps(found))
"""


def test_opencv_and_imageio_read_no_frame_whatever_its_compression(frame_path, tmp_path):
    """In a process with OPENCV_IO_ENABLE_OPENEXR=1 (OpenCV reads the variable once): cv2 reads the
    IR stored alone as a plain Y channel (so its EXR codec is on), and no dotsim frame."""
    frames = [rewritten(frame_path, compression, tmp_path) for compression in ds.EXR_COMPRESSIONS]
    ir = ds.read_frame(frame_path)["ir"]
    control = tmp_path / "plain_y.exr"
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage},
                 {"Y": ir}).write(str(control))
    done = subprocess.run([sys.executable, "-c", READERS, str(control), *map(str, frames)],
                          capture_output=True, text=True, env={**os.environ, "OPENCV_IO_ENABLE_OPENEXR": "1"})
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout)
    assert found[str(control)][0] == ["float32", list(ir.shape)]
    for path in frames:
        cv2_result, imageio_result = found[str(path)]
        assert cv2_result is None and isinstance(imageio_result, str), (path.name, found[str(path)])


def readme_snippets() -> list[str]:
    """The python blocks of the README's "Reading frames" section."""
    text = (REPO / "README.md").read_text()
    section = text[text.index("## Reading frames"):]
    section = section[:section.index("\n## ", 1)]
    return re.findall(r"^```python\n(.*?)^```", section, re.MULTILINE | re.DOTALL)


def test_the_readme_snippets_read_a_frame_and_an_exports_members(frame_path, tmp_path, monkeypatch):
    """Each snippet runs as written, in a folder holding frame_0.exr and an export's shard unpacked, and
    gives what read_frame gives."""
    export = tmp_path / "export"
    assert cli.main(["export", str(frame_path.parents[2]), str(export)]) == 0
    work = tmp_path / "work"
    work.mkdir()
    with tarfile.open(export / "shard-000000.tar") as tar:
        tar.extractall(work, filter="data")
    shutil.copy(frame_path, work / "frame_0.exr")
    monkeypatch.chdir(work)
    frame = ds.read_frame(frame_path)
    snippets = readme_snippets()
    assert len(snippets) == 5
    checked = set()
    for snippet in snippets:
        assert len(snippet.strip().splitlines()) <= 3, snippet
        names: dict = {}
        exec(compile(snippet, "README.md", "exec"), names)  # noqa: S102 (the documentation's own code)
        for name in ("ir", "depth", "disparity"):
            if name in names:
                assert names[name].dtype == frame[name].dtype, (snippet, name)
                assert np.array_equal(names[name], frame[name], equal_nan=True), (snippet, name)
                checked.add(name)
        for name, channel in (("visible", "visibility"), ("edge", "edge")):
            if name in names:
                assert np.array_equal(names[name], frame[channel] > 0), (snippet, name)
                checked.add(name)
    assert checked == {"ir", "depth", "disparity", "visible", "edge"}
