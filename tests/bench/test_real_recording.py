"""bench/real_recording.py's path on the vendored real Kinect frame, at a tiny size (its steps, with
the product's functions: tests do not import benchmarks): the frame shrunk by whole-pixel means,
`dotsim infer` of a tiny network trained on oracle renders of the capture's rig and real pattern
(bench/kinect_real.toml's [rig], a quarter of its size), and the plane score of what it predicts over
the hand-drawn regions."""

from pathlib import Path

import cv2
import numpy as np
import pytest

from commands.cli import main as dotsim
from dotsim.frame_source import open_source
from dotsim.images import write_image
from dotsim.oracle_dataset import make_dataset
from dotsim.patterns import DotPattern, load_pattern
from dotsim.prediction_file import read_prediction
from dotsim.rig.config import read_rig_config
from dotsim.rig.geometry import depth_to_disparity
from dotsim.rig.options import checked_rig
from tests.trainer_fixtures import tiny_config
from trainer.config import config_from_dict
from trainer.flat_regions import read_regions, score_regions
from trainer.train import train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py
REPO = Path(__file__).resolve().parents[2]
REAL = REPO / "tests" / "data" / "real" / "kinect_v1_ctd"


def real_frame(shape: tuple[int, int]) -> np.ndarray:
    """The vendored 640 x 512 IR frame in [0, 1], each pixel of `shape` the mean of its whole-pixel block."""
    ir = cv2.imread(str(REAL / "ir.png"), cv2.IMREAD_UNCHANGED).astype(np.float64) / 255
    h, w = shape
    return ir.reshape(h, ir.shape[0] // h, w, ir.shape[1] // w).mean(axis=(1, 3))


@pytest.fixture(scope="module")
def tiny_network(tmp_path_factory):
    """A tiny network trained 20 steps on oracle renders through kinect_real's rig at a quarter of its size
    (camera 80 x 64, projector 160 x 128) with the capture's pattern shrunk to the projector."""
    rig = checked_rig(*read_rig_config(REPO / "bench" / "kinect_real.toml")).rig.scaled(0.25)
    pattern = load_pattern(REAL / "pattern.png").image
    small = cv2.resize(pattern, (rig.projector.width, rig.projector.height), interpolation=cv2.INTER_AREA)
    dots = DotPattern(small / small.max(), source=str(REAL / "pattern.png"), params={"shrunk": 0.25})
    data = make_dataset(tmp_path_factory.mktemp("ds"), scenes=3, frames_per_scene=2, rig=rig, pattern=dots)
    d = tiny_config(20).to_dict()
    d["model"].update(lines=32, min_depth=0.5)  # 32 half-resolution rows
    run = tmp_path_factory.mktemp("run")
    train(config_from_dict(d, "tiny kinect_real"), open_source(data, "train"), run, progress=False)
    return run / "checkpoint.pt", rig


def test_infer_on_the_real_frame_gives_a_finite_plane_score(tiny_network, tmp_path: Path):
    checkpoint, rig = tiny_network
    frame = tmp_path / "real.png"
    write_image(frame, np.rint(real_frame((rig.camera.height, rig.camera.width)) * 65535).astype(np.uint16))
    assert dotsim(["infer", "--checkpoint", str(checkpoint), str(frame), "--out", str(tmp_path / "inf")]) == 0
    disparity = read_prediction(tmp_path / "inf" / "real.exr")["disparity"]
    assert disparity.shape == (64, 80)
    labels, names = read_regions(REAL / "flat_regions.json", disparity.shape)
    plausible = tuple(float(depth_to_disparity(np.float64(z), rig)) for z in (rig.max_depth, 0.5))
    rows = score_regions(disparity, labels, names, plausible)
    every = rows[-1]
    assert every["region"] == "all" and every["pixels"] == int((labels > 0).sum())
    assert 0.0 <= every["no value"] < 1.0 and np.isfinite(every["rms"]) and every["rms"] >= 0
