"""Metric and resampling against hand-computed cases; SGBM on an exact wall; bad inputs give clear errors."""

from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from commands.cli import main as dotsim_main
from dotsim.frame_source import SourceError, open_source
from dotsim.oracle_dataset import make_dataset, planar_depth, synthetic_frame
from dotsim.patterns import generate_dot_pattern
from dotsim.rig.geometry import reference_image
from dotsim.rig.presets import get_preset
from tests.output_folders import assert_one_line_error, leftovers
from trainer.checkpoint import load_checkpoint, stored_reference
from trainer.config import config_from_dict, load_config
from trainer.evaluate import evaluate
from trainer.infer import infer
from trainer.samples import DataError
from trainer.scoring import HalfResolutionFloor
from trainer.sgbm import num_disparities_for, sgbm_disparity
from trainer.train import train
from trainer.upsampling import upsample_half


def test_upsample_half_is_exact_for_linear_fields():
    for height, width in ((6, 8), (7, 9), (6, 9)):
        v, u = np.mgrid[0:height, 0:width].astype(np.float64)
        field = 0.3 * u - 1.7 * v + 2.0
        half = field[::2, ::2]
        np.testing.assert_allclose(upsample_half(half, height, width), field, atol=1e-12)


def test_upsample_half_takes_the_farther_sample_across_a_depth_jump():
    """Two sloped surfaces (disparity 8 + 0.1 u left of column 5, 3 + 0.1 u from it): pixels between
    samples of one surface are linear (exact), the one between the surfaces gets the farther (smaller)
    disparity, never a value floating between them; without `jump` it is the mean."""
    height, width = 6, 10
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    field = np.where(u < 5, 8.0, 3.0) + 0.1 * u
    half = field[::2, ::2]  # samples at u = 0, 2, 4 (near) and 6, 8 (far)
    up = upsample_half(half, height, width, jump=1.0)
    for col in (0, 1, 2, 3, 4, 6, 7, 8, 9):
        np.testing.assert_allclose(up[:, col], field[:, col], atol=1e-12)
    np.testing.assert_allclose(up[:, 5], 3.6)  # the far sample at u = 6, not (8.4 + 3.6) / 2
    np.testing.assert_allclose(upsample_half(half, height, width)[:, 5], 6.0)
    with_hole = half.copy()
    with_hole[:, 3] = np.nan  # no estimate at u = 6: u = 5 and 7 take their other neighbour
    up = upsample_half(with_hole, height, width, jump=1.0)
    np.testing.assert_allclose(up[:, 5], 8.4)
    np.testing.assert_allclose(up[:, 7], 3.8)
    assert np.isnan(up[:, 6]).all()


def test_half_resolution_floor_misses_only_the_pixel_between_two_surfaces():
    """A near box (disparity 20) before a far wall (disparity 10). Samples sit on even rows and columns;
    a full-resolution pixel on an odd column (row) between a near and a far sample takes the far one, so
    the floor misses the box's pixels on such a column (row) at a box border that starts or ends on an
    even index, and none where the border falls between two samples of the same surface. Counted by hand:
    the box spans rows 3..8 and columns 4..9 (0-based, inclusive). Left border, first box column 4 (even):
    sample 4 is near, so column 3 (between far 2 and near 4) takes far: right, it is wall. Right border,
    last box column 9 (odd): samples 8 (near) and 10 (far); column 9 takes far: wrong, 6 rows. Top, first
    box row 3 (odd): samples 2 (far) and 4 (near); row 3 takes far: wrong. Bottom, last box row 8 (even):
    row 9 between 8 (near) and 10 (far) takes far: right. Row 3 misses box columns 4..8 (5 pixels; its
    column 9 is counted once already), so 6 + 5 = 11 of the 6 x 6 box pixels, nothing else."""
    height, width = 14, 16
    disparity = np.full((height, width), 10.0, np.float32)
    disparity[3:9, 4:10] = 20.0
    predicted = HalfResolutionFloor().predict({"disparity": disparity, "ir": np.zeros_like(disparity)})
    wrong = np.abs(predicted - disparity) > 0.5
    expected = np.zeros_like(wrong)
    expected[3:9, 9] = True
    expected[3, 4:10] = True
    np.testing.assert_array_equal(wrong, expected)
    assert wrong.sum() == 11
    # between two samples of one surface the floor is exact, so off the box's borders nothing is lost
    np.testing.assert_allclose(predicted[~expected], disparity[~expected])


def test_sgbm_on_an_exact_wall_finds_fb_over_z():
    """A fronto-parallel wall at 2 m: disparity fx b / z everywhere SGBM matches (independent formula)."""
    rig = get_preset("structure_core").scaled(0.2)
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=1).image.astype(np.float64)
    depth = planar_depth(rig, 2.0, 0.0, 0.0)
    ir = synthetic_frame(depth, rig, pattern, np.random.default_rng(0), noise=0.0)["ir"]
    disp = sgbm_disparity(ir, reference_image(pattern, rig, supersample=4), num_disparities_for(rig, 2.0))
    want = rig.camera.fx * rig.baseline / 2.0
    inner = disp[10:-10, 40:-10]
    assert np.isfinite(inner).mean() > 0.95
    assert np.nanmedian(np.abs(inner - want)) < 0.25, (np.nanmedian(inner), want)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # the shared 2-core machine: two threads were 3-10x slower per step
    data = make_dataset(tmp_path_factory.mktemp("ds"), scenes=1, frames_per_scene=2, test_scenes=1)
    cfg = load_config("dotsim/configs/train_tiny.toml").to_dict()
    cfg["train"].update(max_steps=1, batch_size=2)
    out = tmp_path_factory.mktemp("run")
    train(config_from_dict(cfg, "t"), open_source(data, "train"), out, progress=False)
    yield {"data": data, "ckpt": out / "checkpoint.pt", "cfg": cfg, "out": out}
    torch.set_num_threads(threads)


def test_empty_or_missing_data_folder(tmp_path, run):
    with pytest.raises(SourceError, match=r"index\.json: missing"):
        train(load_config("dotsim/configs/train_tiny.toml"), open_source(tmp_path, "train"), tmp_path / "o",
              progress=False)
    with pytest.raises(SourceError, match="does not exist"):
        evaluate(run["ckpt"], open_source(tmp_path / "nope", "test"), tmp_path / "e", progress=False)
    with pytest.raises(SourceError, match=r"no scenes with split 'val'.*'train': 1"):
        evaluate(run["ckpt"], open_source(run["data"], "val"), tmp_path / "e", progress=False)


def test_data_of_another_rig_or_resolution(tmp_path, run):
    other = make_dataset(tmp_path / "other", scenes=0, test_scenes=1, frames_per_scene=1, scale=0.08)
    with pytest.raises(DataError, match=r"97x72.*differs from the checkpoint.*122x90"):
        evaluate(run["ckpt"], open_source(other, "test"), tmp_path / "e", progress=False)
    png = tmp_path / "small.png"
    cv2.imwrite(str(png), np.zeros((72, 97), np.uint16))
    with pytest.raises(DataError, match=r"small\.png: image is 97x72.*122x90"):
        infer(run["ckpt"], [png], tmp_path / "i", progress=False)
    assert not (tmp_path / "i").exists()  # bad input: not even an empty output folder


def test_resume_refuses_another_config_and_overwrite(run):
    cfg = run["cfg"]
    with pytest.raises(DataError, match="pass --resume"):
        train(config_from_dict(cfg, "t"), open_source(run["data"], "train"), run["out"], progress=False)
    changed = {**cfg, "model": {**cfg["model"], "lines": 4}}
    with pytest.raises(DataError, match="another config"):
        train(config_from_dict(changed, "t"), open_source(run["data"], "train"), run["out"], resume=True,
              progress=False)


def test_not_a_checkpoint(tmp_path, run):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    with pytest.raises(DataError, match=r"bad\.pt: not a readable torch checkpoint"):
        evaluate(bad, open_source(run["data"], "test"), tmp_path / "e", progress=False)
    torch.save({"weights": 1}, bad)
    with pytest.raises(DataError, match="not a dotsim trainer checkpoint"):
        infer(bad, [bad], tmp_path / "i", progress=False)


@pytest.mark.parametrize("command", ["train", "eval", "infer"])
def test_cli_reports_errors_in_one_line_on_stderr(tmp_path, capsys, run, command):
    args = {"train": ["--config", "dotsim/configs/train_tiny.toml", "--data", str(tmp_path / "nodata"),
                      "--out", str(tmp_path / "r")],
            "eval": ["--checkpoint", str(tmp_path / "none.pt"), "--data", str(run["data"]),
                     "--out", str(tmp_path / "e")],
            "infer": ["--checkpoint", str(tmp_path / "none.pt"), str(tmp_path / "x.png"),
                      "--out", str(tmp_path / "i")]}[command]
    code = dotsim_main([command, *args])
    captured = capsys.readouterr()
    assert code == 1 and captured.out == ""
    assert captured.err.startswith(f"dotsim {command}: error: ") and captured.err.count("\n") == 1
    assert ("nodata" if command == "train" else "none.pt: checkpoint not found") in captured.err


def test_cli_train_eval_infer_run_and_write_their_files(tmp_path, run):
    cfg = Path("dotsim/configs/train_tiny.toml").read_text().replace("max_steps = 200", "max_steps = 1")
    (tmp_path / "c.toml").write_text(cfg.replace("batch_size = 4", "batch_size = 2"))
    out = tmp_path / "run"
    assert dotsim_main(["train", "--config", str(tmp_path / "c.toml"), "--data", str(run["data"]),
                        "--out", str(out), "--max-steps", "2", "--val-data", str(run["data"]),
                        "--val-split", "test", "--val-frames", "1"]) == 0
    assert load_checkpoint(out / "checkpoint.pt")[0]["step"] == 2  # --max-steps over the config's 1
    assert dotsim_main(["eval", "--checkpoint", str(out / "checkpoint.pt"), "--data", str(run["data"]),
                        "--out", str(tmp_path / "eval"), "--images", "1"]) == 0
    frame = next(Path(run["data"]).glob("shard_*/scene_0000001/frame_0.exr"))
    assert dotsim_main(["infer", "--checkpoint", str(out / "checkpoint.pt"), str(frame),
                        "--out", str(tmp_path / "inf")]) == 0
    assert (tmp_path / "eval" / "eval.csv").is_file()
    assert len(list((tmp_path / "eval" / "errors").iterdir())) == 1
    assert sorted(p.name for p in (tmp_path / "inf").iterdir()) == [
        "scene_0000001_frame_0.exr", "scene_0000001_frame_0.ply", "scene_0000001_frame_0.png"]


def test_config_resolution_mismatch_is_named():
    """train_cpu's 112 lines divide 608 x 448's 224 half-resolution rows, and train_tiny's 45 the 45 of
    the generator's tiny config (122 x 90: `--config tiny` data trains without a warning); train_tiny on
    608 x 448 does not fit, and the message says which rows and what to choose."""
    from generator.config import load_config as load_generator_config
    from generator.sample_scene import build_rig
    from trainer.config import resolution_mismatch

    assert resolution_mismatch(load_config("train_cpu"), 608, 448) is None
    tiny = build_rig(load_generator_config("tiny")).camera
    assert (tiny.width, tiny.height) == (122, 90)
    assert resolution_mismatch(load_config("train_tiny"), tiny.width, tiny.height) is None
    message = resolution_mismatch(load_config("train_tiny"), 608, 448)
    assert "lines = 45" in message and "224 half-resolution rows" in message
    assert "4.98 rows per line" in message
    assert "lines = 112" in resolution_mismatch(load_config("train_cpu"), 122, 90)  # 112 > 45 rows


def test_train_table2_fits_the_table2_camera_standing_upright():
    """--config table2 renders DepthInSpace's camera, 432 px wide and 512 px tall: train_table2's lines
    cover its 256 half-resolution rows one each (the 54 of the camera lying on its side do not fit)."""
    from dataclasses import replace

    from dotsim.rig.config import read_rig_config
    from dotsim.rig.options import checked_rig
    from trainer.config import resolution_mismatch

    camera = checked_rig(*read_rig_config("table2")).rig.camera  # [rig] alone: CI has no asset cache built
    assert (camera.width, camera.height) == (432, 512)
    cfg = load_config("train_table2")
    assert cfg.model.lines == 512 // 2 and resolution_mismatch(cfg, 432, 512) is None
    old = replace(cfg, model=replace(cfg.model, lines=54))
    assert "lines = 54" in resolution_mismatch(old, 432, 512)


def test_eval_chooses_sgbm_on_validation_frames_never_the_test(run, tmp_path):
    """The SGBM variant the verdict uses is the one with the lower o(0.5) on the validation frames (here
    the train split, scored separately by a full evaluate of it), and validation frames overlapping the
    evaluated ones are refused."""
    rows = evaluate(run["ckpt"], open_source(run["data"], "test"), tmp_path / "e", progress=False,
                    validation=open_source(run["data"], "train"))
    chosen = {r["method"] for r in rows if r["chosen"]}
    assert len(chosen) == 1 and chosen <= {"sgbm-plain", "sgbm-lcn"}
    on_train = evaluate(run["ckpt"], open_source(run["data"], "train"), tmp_path / "t", progress=False)
    rates = {r["method"]: r["o(0.5)"] for r in on_train
             if r["range"] == "all" and r["method"].startswith("sgbm-")}
    assert min(rates, key=rates.get) == chosen.pop()
    assert {r["range"] for r in rows if r["method"] == "half-res floor"} >= {"all", "edge", "off edge"}
    assert "half-res floor: the GT disparity taken at" in (tmp_path / "e" / "eval.md").read_text()
    assert "chosen on 2 validation frame(s)" in (tmp_path / "e" / "eval.md").read_text()
    with pytest.raises(SourceError, match="overlap the evaluated frames"):
        evaluate(run["ckpt"], open_source(run["data"], "test"), tmp_path / "o", progress=False,
                 validation=open_source(run["data"], "test"))


def _command(command: str, run: dict, out: Path) -> list[str]:
    """`dotsim COMMAND ... --out out` on the module's run and data."""
    frame = next(Path(run["data"]).glob("shard_*/scene_0000001/frame_0.exr"))
    return {"train": ["train", "--config", "dotsim/configs/train_tiny.toml", "--data", str(run["data"]),
                      "--out", str(out)],
            "eval": ["eval", "--checkpoint", str(run["ckpt"]), "--data", str(run["data"]), "--out", str(out),
                     "--images", "1"],
            "infer": ["infer", "--checkpoint", str(run["ckpt"]), str(frame), "--out", str(out)]}[command]


@pytest.mark.parametrize("command", ["train", "eval", "infer"])
@pytest.mark.parametrize("inside", [False, True])
def test_a_read_only_output_folder_is_one_line_and_nothing_written(command, inside, run, read_only_folder,
                                                                   capsys):
    """--out the read-only folder itself, or a new folder inside it (issue 37, item 1)."""
    out = read_only_folder / "run" if inside else read_only_folder
    assert dotsim_main(_command(command, run, out)) == 1
    assert_one_line_error(capsys.readouterr().err, f"--out {out}: {read_only_folder} is not writable")
    assert not any(read_only_folder.iterdir())


@pytest.mark.parametrize("command", ["eval", "infer"])
def test_a_full_output_folder_is_one_line_and_nothing_half_written(command, run, tmp_path, no_space,
                                                                   capsys):
    """(A full disk during training: tests/generator/test_reliability.py.)"""
    assert dotsim_main(_command(command, run, tmp_path / "out")) == 1
    assert_one_line_error(capsys.readouterr().err, tmp_path / "out", "no space left on device")
    assert not leftovers(tmp_path)


def test_a_train_that_fails_before_its_first_checkpoint_leaves_no_run(tmp_path, run, capsys):
    """Issue 45: a failed train left RUN/tb behind, a folder that looks like a run but cannot resume.
    Here every frame is damaged after sealing, so the first batch fails its checksum; an existing empty
    --out folder stays (empty), a new one is not left behind."""
    data = make_dataset(tmp_path / "data", scenes=2, frames_per_scene=2)  # one batch of train_tiny
    for frame in data.glob("shard_*/scene_*/frame_*.exr"):
        frame.write_bytes(frame.read_bytes() + b"damage")
    toml = tmp_path / "train.toml"
    toml.write_text(Path("dotsim/configs/train_tiny.toml").read_text())
    for out in (tmp_path / "new_run", tmp_path / "empty"):
        if out.name == "empty":
            out.mkdir()
        assert dotsim_main(["train", "--config", str(toml), "--data", str(data), "--out", str(out),
                            "--max-steps", "1", "--no-progress"]) == 1
        assert_one_line_error(capsys.readouterr().err, "frame_")
        assert (out.is_dir() and not any(out.iterdir())) if out.name == "empty" else not out.exists()


def test_eval_of_data_without_ground_truth_says_there_is_nothing_to_score(tmp_path, run, capsys):
    """Issue 45 items 14 and 15: a capture (no depth) said "pattern.png: no such file", an export of
    the IR alone "it has []"; both now name what the frames store and what eval needs, and write
    nothing."""
    from dotsim.shards.writer import export_webdataset

    ir_only = export_webdataset(run["data"], tmp_path / "ir_only", channels=["ir"]).out
    rng = np.random.default_rng(0)
    for name in ("on", "off"):
        (tmp_path / name).mkdir()
        for k in range(2):
            cv2.imwrite(str(tmp_path / name / f"f_{k}.png"), rng.integers(0, 256, (90, 122), dtype=np.uint8))
    captured = tmp_path / "captured"
    assert dotsim_main(["capture", "import", "--on", str(tmp_path / "on"), "--off", str(tmp_path / "off"),
                        "--scale", "0.1", "--frames-per-scene", "2", "--out", str(captured),
                        "--no-progress"]) == 0
    capsys.readouterr()
    for data, stored, missing in ((ir_only, "ir", "visibility, disparity, edge"),
                                  (captured, "ambient, ir, visibility", "disparity, edge")):
        out = tmp_path / f"eval_{data.name}"
        assert dotsim_main(["eval", "--checkpoint", str(run["ckpt"]), "--data", str(data), "--split", "all",
                            "--out", str(out), "--no-progress"]) == 1
        assert_one_line_error(capsys.readouterr().err, f"{data}: its frames store {stored}, not {missing}: "
                              "nothing to score")
        assert not out.exists()


def test_training_on_frames_with_nothing_visible_says_so(tmp_path, run, capsys):
    """Issue 45: frames with no visible pixel trained with loss 0 and no word."""
    from dotsim.channels import rendered_channels
    from dotsim.dataset import seal_dataset, write_scene

    rig = get_preset("structure_core").scaled(0.1)
    dots = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=0)
    rng, pattern = np.random.default_rng(0), np.asarray(dots.image, np.float64)
    frames = []
    for _ in range(4):
        frame = synthetic_frame(planar_depth(rig, 1.5, 0.0, 0.1), rig, pattern, rng)
        frame["visibility"][:] = 0
        frames.append(frame)
    dark = tmp_path / "dark"
    write_scene(dark, 0, {"split": "train", "rig": rig.to_dict(), "pattern": {"sha256": dots.sha256},
                          "poses": [np.eye(4).tolist()] * 4}, frames, channels=rendered_channels(False))
    seal_dataset(dark)
    cfg = config_from_dict({**run["cfg"], "train": {**run["cfg"]["train"], "max_steps": 2}}, "t")
    capsys.readouterr()
    result = train(cfg, open_source(dark, "train"), tmp_path / "run", progress=True, progress_bar=False)
    assert result["losses"] == [0.0, 0.0]
    err = capsys.readouterr().err
    assert "the loss was 0 at every one of 2 step(s): the training frames show no visible pixel" in err
    # this dataset has no pattern.png: it trains, and the checkpoint keeps no pattern, saying so
    assert "no pattern to keep in the checkpoint" in err and "pattern.png: no such file" in err
    assert stored_reference(tmp_path / "run" / "checkpoint.pt", rig) is None
