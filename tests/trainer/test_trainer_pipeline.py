"""Trainer end to end on a tiny oracle-rendered dataset: data alignment, training, resume, eval, infer."""

import csv
import dataclasses
import time

import cv2
import numpy as np
import pytest
import torch

from dotsim.config_schema import ConfigError
from dotsim.dataset import read_frame
from dotsim.false_colour import LINE, colourise
from dotsim.frame_source import FrameRef, SourceError, open_source
from dotsim.lcn import lcn
from dotsim.patterns import load_pattern
from dotsim.prediction_file import prediction_source
from dotsim.rig.geometry import depth_to_disparity, projector_column_to_depth, reference_image
from dotsim.solvable import pattern_snr
from tests.trainer_fixtures import tiny_config
from trainer.checkpoint import load_checkpoint, load_model, predict_disparity, stored_reference
from trainer.config import config_from_dict
from trainer.evaluate import evaluate
from trainer.infer import infer
from trainer.model import build_model
from trainer.samples import FrameDataset
from trainer.sgbm import sgbm_disparity
from trainer.train import batch_loss, train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


@pytest.fixture(scope="module")
def trained(data, tmp_path_factory):
    """A tiny network after 20 steps, and its loss on a fixed batch before and after training."""
    cfg = tiny_config(20, lr=0.01)
    source = open_source(data, "train")
    frames, rig = source.frames, source.rig
    fixed = FrameDataset(frames[:4], rig, cfg.data, seed=0, augment=False)
    batch = {k: torch.stack([fixed[i][k] for i in range(4)]) for k in fixed[0]}

    def fixed_loss(model):
        with torch.no_grad():
            return float(batch_loss(model, batch, cfg)[0])

    torch.manual_seed(cfg.seed)
    before = fixed_loss(build_model(cfg, rig))
    run = tmp_path_factory.mktemp("run")
    result = train(cfg, open_source(data, "train"), run, progress=False, val_frames=2,
                   validation=open_source(data, "test"))
    ckpt, _, _ = load_checkpoint(run / "checkpoint.pt")
    model = build_model(cfg, rig)
    model.load_state_dict(ckpt["model"])
    return {"run": run, "before": before, "after": fixed_loss(model), "result": result, "cfg": cfg}


def test_training_lowers_the_loss_on_a_fixed_batch(trained):
    assert trained["result"]["step"] == 20
    assert trained["after"] < 0.95 * trained["before"], (trained["before"], trained["after"])
    assert (trained["run"] / "tb").is_dir() and any((trained["run"] / "tb").iterdir())


def test_same_seed_same_losses_and_resume_continues_identically(data, tmp_path):
    straight = train(tiny_config(6), open_source(data, "train"), tmp_path / "a", progress=False)["losses"]
    first = train(tiny_config(3), open_source(data, "train"), tmp_path / "b", progress=False)["losses"]
    rest = train(tiny_config(6), open_source(data, "train"), tmp_path / "b", resume=True,
                 progress=False)["losses"]
    assert first == straight[:3]  # two runs, same seed: bit-identical
    assert first + rest == straight  # 3 steps + resume for 3 more == 6 unbroken steps
    assert straight[0] != straight[1]


@pytest.mark.parametrize("schedule", ["cosine", "piecewise"])
def test_annealing_schedules_follow_their_formula_over_the_run(data, tmp_path, schedule):
    """The learning rate TensorBoard records per step is lr x the schedule's factor at that step of the
    run's total, written out here; a resumed, extended run follows the schedule of its new total."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    def logged(run):  # a resumed run's writer purges what was logged after its checkpoint, no more
        return [e.value for e in EventAccumulator(str(run / "tb")).Reload().Scalars("lr")]

    cfg = tiny_config(10, lr_schedule=schedule, log_every=1, lr=0.01, lr_final=0.05)
    train(cfg, open_source(data, "train"), tmp_path / "a", progress=False)
    # the rate of optimiser step k (1-based) is logged after the scheduler moved on: factor at step k
    if schedule == "cosine":
        want = [0.01 * (0.05 + 0.95 * 0.5 * (1 + np.cos(np.pi * k / 10))) for k in range(1, 11)]
    else:  # [1, .5, .25, .12, .01], each for 2 of the 10 steps
        want = [0.01 * f for f in (1, .5, .5, .25, .25, .12, .12, .01, .01, .01)]
    np.testing.assert_allclose(logged(tmp_path / "a"), want, rtol=1e-6)
    train(tiny_config(4, lr_schedule=schedule, log_every=1, lr=0.01, lr_final=0.05),
          open_source(data, "train"), tmp_path / "b", progress=False)
    # TensorBoard orders a run's event files by name: second, host, pid, then the process's writer
    # count, unpadded. Two writers of one process in one second sort as text (writer 10 before 9), and
    # the resumed file read first hid the steps before it (seen in the full suite). A resumed run is
    # another process, or another second, in use; so it is here.
    time.sleep(1.1)
    train(cfg, open_source(data, "train"), tmp_path / "b", resume=True, progress=False)
    resumed = logged(tmp_path / "b")
    assert len(resumed) == 10
    np.testing.assert_allclose(resumed[4:], want[4:], rtol=1e-6)


def test_loader_workers_do_not_change_the_run(data, tmp_path):
    """Augmentations are keyed by (seed, epoch, frame), so 2 worker processes give the same losses."""
    cfg = tiny_config(2).to_dict()
    cfg["data"]["workers"] = 2
    with_workers = train(config_from_dict(cfg, "workers"), open_source(data, "train"), tmp_path / "w",
                         progress=False)["losses"]
    assert with_workers == train(tiny_config(2), open_source(data, "train"), tmp_path / "n",
                                 progress=False)["losses"]


@pytest.mark.parametrize("stride", [2, 1])
def test_samples_keep_line_identity_and_target_alignment(data, stride):
    """A crop's targets are the full frame's at (y0 + stride i, x0 + stride j), its row0 = y0 / stride
    and x0 its first column ([model] stride 2: half resolution, 1: full)."""
    cfg = tiny_config(1)
    plain = dataclasses.replace(cfg.data, noise_std=0.0, intensity_scale=(1.0, 1.0))
    cfg = dataclasses.replace(cfg, data=plain)
    source = open_source(data, "train")
    frames, rig = source.frames, source.rig
    ds = FrameDataset(frames, rig, cfg.data, seed=3, augment=True, stride=stride)
    for i in range(3):
        s = ds[i]
        full = read_frame(frames[i].path)
        ir = full["ir"].astype(np.float32)
        crop = s["ir"][0].numpy()
        ch, cw = crop.shape
        hits = [(y, x) for y in range(ir.shape[0] - ch + 1) for x in range(ir.shape[1] - cw + 1)
                if np.array_equal(ir[y : y + ch, x : x + cw], crop)]
        assert len(hits) == 1
        y0, x0 = hits[0]
        assert y0 % stride == 0 and int(s["row0"]) == y0 // stride and int(s["x0"]) == x0
        at = (slice(y0, y0 + 48, stride), slice(x0, x0 + 64, stride))
        col = full["projector_column"][at] / rig.projector.width
        valid = s["valid"].numpy()
        np.testing.assert_array_equal(s["column"].numpy()[valid], col[valid].astype(np.float32))
        np.testing.assert_array_equal(valid, (full["visibility"][at] > 0) & np.isfinite(col) & (col >= 0)
                                      & (col <= 1))


def test_a_full_resolution_network_trains_and_predicts_every_pixel(data, tmp_path):
    """[model] stride 1: the backbone keeps full resolution, one line per camera row, and the disparity
    of every pixel is the network's own (no upsampling): converted back to a column it is the output."""
    cfg = tiny_config(3)
    cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, stride=1, lines=90))
    result = train(cfg, open_source(data, "train"), tmp_path / "run", progress=False)
    assert len(result["losses"]) == 3 and np.isfinite(result["losses"]).all()
    model, _, rig = load_model(tmp_path / "run" / "checkpoint.pt")
    frames = open_source(data, "test").frames
    ir = read_frame(frames[0].path)["ir"].astype(np.float32)
    with torch.no_grad():
        column = model(torch.from_numpy(ir)[None, None])[0].numpy()
    assert column.shape == ir.shape
    disparity = predict_disparity(model, rig, ir)[0]
    want = depth_to_disparity(projector_column_to_depth(column, rig, normalised=True), rig)
    np.testing.assert_array_equal(disparity, want)


def test_model_input_lcn_equals_numpy_lcn(data):
    cfg = tiny_config(1)
    source = open_source(data, "train")
    frames, rig = source.frames, source.rig
    ir = read_frame(frames[0].path)["ir"].astype(np.float32)
    x = build_model(cfg, rig).inputs(torch.from_numpy(ir)[None, None])
    np.testing.assert_array_equal(x[0, 0].numpy(), ir)
    np.testing.assert_allclose(x[0, 1].numpy(), lcn(ir.astype(np.float64), cfg.model.lcn_window,
                                                    cfg.model.lcn_eps), rtol=1e-5, atol=1e-5)


def test_eval_table_matches_independent_count_from_infer_output(data, trained, tmp_path):
    rows = evaluate(trained["run"] / "checkpoint.pt", open_source(data, "test"), tmp_path / "eval",
                    progress=False)
    md = (tmp_path / "eval" / "eval.md").read_text()
    assert "| network | all |" in md and "| sgbm-plain | all |" in md and "| sgbm-lcn | all |" in md
    assert "verdict: the network is" in md and "10.4-12.9 %" in md  # GigaDepth's reference figures
    assert "| network | solvable |" in md and "| all | 0.5 |" in md and "feasible disparity range" in md
    with open(tmp_path / "eval" / "eval.csv") as f:
        table = list(csv.DictReader(f))
    # network, SGBM plain and LCN, the half-res floor; all, 5 ranges; edge, off edge, slanted, (not) solvable
    assert len(table) == len(rows) == 4 * (6 + 5)
    pngs = sorted((tmp_path / "eval" / "errors").glob("*.png"))
    assert len(pngs) == 2
    # 122 x 90 frames: each panel scaled up twice (nearest) under a title bar, the IR untouched by text
    strip = cv2.imread(str(pngs[0]))
    assert strip.shape[1] == 3 * 244 + 2 * 2
    scene, _, k = pngs[0].stem.removeprefix("scene_").partition("_frame_")
    frame = next(f for f in open_source(data, "test").frames
                 if (f.scene_index, f.frame_index) == (int(scene), int(k)))
    ir = read_frame(frame.path)["ir"].astype(np.float32)
    grey = np.clip(ir / max(float(np.percentile(ir, 99.5)), 1e-12) * 255, 0, 255).astype(np.uint8)
    panel = strip[LINE:LINE + 2 * 90, :244]
    assert np.array_equal(panel, np.repeat(np.repeat(grey, 2, 0), 2, 1)[..., None].repeat(3, 2))
    # recompute the network's overall and edge o(1) and the joint table's "only the network" at 0.5 px
    # from infer's EXRs, SGBM and the GT, by hand
    source = open_source(data, "test")
    frames, rig = source.frames, source.rig
    infer(trained["run"] / "checkpoint.pt", [f.path for f in frames], tmp_path / "inf", progress=False)
    import OpenEXR

    over = total = 0
    edge = [0, 0]  # outliers at 1 px on the edge mask, its pixels
    only_network = 0  # valid pixels the network gets wrong at 0.5 px and plain SGBM (chosen here) right
    reference = reference_image(load_pattern(data / "pattern.png").image, rig, supersample=4)
    for f in frames:
        gt = read_frame(f.path)
        pred = OpenEXR.File(str(tmp_path / "inf" / f"{f.path.parent.name}_{f.path.stem}.exr"),
                            separate_channels=True).channels()["disparity"].pixels
        valid = (gt["visibility"] > 0) & np.isfinite(gt["disparity"]) & (gt["disparity"] > 0)
        err = np.abs(pred.astype(np.float64) - gt["disparity"])
        over += int(np.sum(~(err[valid] <= 1.0)))
        total += int(valid.sum())
        on_edge = valid & (gt["edge"] > 0)
        edge[0] += int(np.sum(~(err[on_edge] <= 1.0)))
        edge[1] += int(on_edge.sum())
        sgbm = sgbm_disparity(gt["ir"].astype(np.float32), reference, 16)
        sgbm_err = np.abs(sgbm.astype(np.float64) - gt["disparity"])
        only_network += int((valid & ~(err <= 0.5) & (sgbm_err <= 0.5)).sum())
    net = next(r for r in table if r["method"] == "network" and r["range"] == "all")
    assert int(net["pixels"]) == total
    assert float(net["o(1)"]) == pytest.approx(over / total, abs=1e-12)
    net_edge = next(r for r in table if r["method"] == "network" and r["range"] == "edge")
    assert int(net_edge["pixels"]) == edge[1] and float(net_edge["o(1)"]) == pytest.approx(edge[0] / edge[1])
    assert "SGBM: 16 disparities" in md
    only = float(next(line for line in md.splitlines() if line.startswith("| all | 0.5 |")).split("|")[4])
    assert only == pytest.approx(only_network / total, abs=1e-4)


def test_validation_while_training_scores_the_held_out_frames(data, trained, tmp_path):
    """The validation rates train() ends with are the final network's o(t) on the held-out frames,
    recounted here from infer's output; they are in TensorBoard with an image, and the training frames
    are refused as validation frames."""
    import OpenEXR
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    source = open_source(data, "test")

    frames, rig = source.frames, source.rig
    infer(trained["run"] / "checkpoint.pt", [f.path for f in frames], tmp_path / "inf", progress=False)
    pattern = np.asarray(load_pattern(data / "pattern.png").image, np.float64)
    counts = {"all": [0, 0], "solvable": [0, 0]}
    for f in frames:
        gt = read_frame(f.path)
        pred = OpenEXR.File(str(tmp_path / "inf" / f"{f.path.parent.name}_{f.path.stem}.exr"),
                            separate_channels=True).channels()["disparity"].pixels.astype(np.float64)
        valid = (gt["visibility"] > 0) & np.isfinite(gt["disparity"]) & (gt["disparity"] > 0)
        snr = pattern_snr(gt["ir"], gt["depth"], rig, pattern,
                          {"read_noise": 0.01, "shot_noise": 0.0, "bit_depth": 12})  # make_dataset's sensor
        wrong = ~(np.abs(pred - gt["disparity"]) <= 0.5)
        for name, selected in (("all", valid), ("solvable", valid & (snr >= 10))):
            counts[name][0] += int((wrong & selected).sum())
            counts[name][1] += int(selected.sum())
    rates = trained["result"]["validation"]
    assert 0 < counts["solvable"][1] < counts["all"][1]
    for name, (over, total) in counts.items():
        assert rates[f"{name} o(0.5)"] == pytest.approx(over / total, abs=1e-12)
    events = EventAccumulator(str(trained["run"] / "tb")).Reload()
    assert "validation/solvable o(5)" in events.Tags()["scalars"]
    (image,) = events.Images("validation/ir_and_error_0_to_5_px")
    # the error strip eval draws too (trainer.scoring.error_strip): IR | network |err|, titled, a legend
    assert image.width >= 2 * rig.camera.width and image.height > rig.camera.height
    with pytest.raises(SourceError, match="validation frames .* overlap the training frames"):
        train(trained["cfg"], open_source(data, "train"), tmp_path / "again", progress=False,
              validation=open_source(data, "all"))


def test_infer_writes_exr_png_ply_from_frames_and_plain_images(data, trained, tmp_path):
    source = open_source(data, "test")
    frames, rig = source.frames, source.rig
    ir = read_frame(frames[0].path)["ir"].astype(np.float32)
    png = tmp_path / "captured.png"
    cv2.imwrite(str(png), np.round(np.clip(ir, 0, 1) * 65535).astype(np.uint16))
    infer(trained["run"] / "checkpoint.pt", [png], tmp_path / "out", progress=False)
    import OpenEXR

    ch = OpenEXR.File(str(tmp_path / "out" / "captured.exr"), separate_channels=True).channels()
    assert prediction_source(tmp_path / "out" / "captured.exr") == {  # marked as a prediction, and whose
        "checkpoint": str((trained["run"] / "checkpoint.pt").resolve()), "input": str(png.resolve()),
        "precision": "float32"}
    depth, disp = ch["depth"].pixels, ch["disparity"].pixels
    finite = np.isfinite(depth)
    np.testing.assert_allclose(disp[finite], rig.camera.fx * rig.baseline / depth[finite], rtol=1e-5)
    ok = finite & (depth <= rig.max_depth)
    colour = cv2.imread(str(tmp_path / "out" / "captured.png"))
    # a 122 px frame scaled up 4 times (nearest: 4 x 4 blocks), so its legend is readable, drawn under it
    lo, hi = np.percentile(disp[np.isfinite(disp)], [1, 99])
    assert colour.shape[1] == 488 and colour.shape[0] > 4 * 90
    assert np.array_equal(colour[:4 * 90], np.repeat(np.repeat(colourise(disp, lo, hi), 4, 0), 4, 1))
    import trimesh

    cloud = trimesh.load(tmp_path / "out" / "captured.ply")  # PLY read back by trimesh's own parser
    assert isinstance(cloud, trimesh.PointCloud) and len(cloud.vertices) == int(ok.sum())
    pts = {axis: cloud.vertices[:, k] for k, axis in enumerate("xyz")}
    v, u = np.nonzero(ok)  # PLY points in row-major pixel order: x = (u - cx) z / fx by hand
    np.testing.assert_allclose(pts["z"], depth[ok], rtol=1e-6)
    cam = rig.camera
    np.testing.assert_allclose(pts["x"], (u - cam.cx) * depth[ok] / cam.fx, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(pts["y"], (v - cam.cy) * depth[ok] / cam.fy, rtol=1e-5, atol=1e-6)


def test_infer_point_cloud_keeps_depths_within_max_depth(data, trained, tmp_path):
    """A checkpoint whose rig's max_depth lies among the predicted depths (the median of those a
    rig's max_depth may be: from 0.5 m): the PLY holds exactly the pixels with a depth up to it,
    none beyond (the EXR keeps every depth)."""
    import OpenEXR

    frames = open_source(data, "test").frames
    infer(trained["run"] / "checkpoint.pt", [frames[0].path], tmp_path / "full", progress=False)
    name = f"{frames[0].path.parent.name}_{frames[0].path.stem}"
    depth = OpenEXR.File(str(tmp_path / "full" / f"{name}.exr"), separate_channels=True
                         ).channels()["depth"].pixels
    limit = float(np.median(depth[np.isfinite(depth) & (depth >= 0.5)]))
    ckpt = torch.load(trained["run"] / "checkpoint.pt", weights_only=False)
    ckpt["rig"]["max_depth"] = limit
    torch.save(ckpt, tmp_path / "near.pt")
    infer(tmp_path / "near.pt", [frames[0].path], tmp_path / "near", progress=False)
    import trimesh

    z = trimesh.load(tmp_path / "near" / f"{name}.ply").vertices[:, 2]  # read back by trimesh's parser
    kept = np.isfinite(depth) & (depth > 0) & (depth <= limit)
    assert 0 < len(z) == int(kept.sum()) < int(np.isfinite(depth).sum())
    assert z.max() <= limit
    np.testing.assert_array_equal(np.sort(z), np.sort(depth[kept]))


def test_unet_backbone_trains_a_step(data, tmp_path):
    cfg = tiny_config(2)
    d = cfg.to_dict()
    d["model"].update(backbone="unet", unet_channels=[16, 16])
    result = train(config_from_dict(d, "unet"), open_source(data, "train"), tmp_path, progress=False)
    assert result["step"] == 2 and all(np.isfinite(result["losses"]))


def test_cached_frames_give_the_same_samples_and_are_read_once(data, monkeypatch):
    """[data].cache_mb keeps decoded frames: two epochs give the samples an uncached dataset gives,
    each frame is read once, a sample changed in place leaves the cache as read, and cache_mb = 0
    keeps nothing."""
    cfg = tiny_config(1)
    source = open_source(data, "train")
    frames, rig = source.frames, source.rig
    reads, read = [], FrameRef.read

    def counted_read(ref, channels):
        reads.append(ref.frame_index)
        return read(ref, channels)

    monkeypatch.setattr(FrameRef, "read", counted_read)
    plain = FrameDataset(frames, rig, cfg.data, seed=5, augment=True)
    cached = FrameDataset(frames, rig, dataclasses.replace(cfg.data, cache_mb=64), seed=5, augment=True)
    for epoch in (0, 1):
        plain.epoch = cached.epoch = epoch
        for i in range(len(frames)):
            a, b = plain[i], cached[i]
            assert a.keys() == b.keys()
            for key in a:
                torch.testing.assert_close(a[key], b[key], rtol=0, atol=0)
            b["ir"] += 1.0
            b["column"] += 1.0
    assert len(reads) == 2 * len(frames) + len(frames)  # plain twice, cached once
    first = read_frame(frames[0].path)
    np.testing.assert_array_equal(cached.targets(0)["ir"], first["ir"].astype(np.float32))
    plain[0]
    assert not plain._cached


def test_cache_with_loader_workers_is_refused():
    d = tiny_config(1).to_dict()
    d["data"].update(cache_mb=100, workers=2)
    with pytest.raises(ConfigError, match=r"\[data\] cache_mb.*workers = 0"):
        config_from_dict(d, "cache.toml")


def test_infer_by_its_command_draws_a_bar_unless_told_not_to(data, trained, tmp_path, capsys):
    """`dotsim infer -o DIR` (the one output spelling) with and without --no-progress: the same files,
    the bar (tqdm, on stderr) only without it; the line saying what was written either way."""
    from commands.cli import main

    frames = open_source(data, "test").frames
    argv = ["infer", "--checkpoint", str(trained["run"] / "checkpoint.pt"), str(frames[0].path)]
    assert main([*argv, "-o", str(tmp_path / "bar")]) == 0
    out, err = capsys.readouterr()
    assert "infer: 100%" in err and "wrote disparity/depth EXR, PNG and PLY for 1 frame(s)" in out
    assert main([*argv, "--out", str(tmp_path / "quiet"), "--no-progress"]) == 0
    out, err = capsys.readouterr()
    assert "infer:" not in err and "wrote disparity/depth EXR, PNG and PLY for 1 frame(s)" in out
    assert sorted(p.name for p in (tmp_path / "bar").iterdir()) == \
        sorted(p.name for p in (tmp_path / "quiet").iterdir())


def test_a_checkpoint_keeps_its_training_pattern_for_the_depth_edges(data, trained, tmp_path, capsys):
    """The checkpoint stores the training data's pattern: infer matches a stride-2 network's depth
    edges against it as eval does against the data's (their agreement: the eval-from-infer test above).
    A checkpoint saved before checkpoints stored one gives the farther sample there, and infer says so."""
    import OpenEXR

    source = open_source(data, "train")
    ckpt_path = trained["run"] / "checkpoint.pt"
    want = reference_image(load_pattern(data / "pattern.png").image, source.rig, supersample=4)
    np.testing.assert_array_equal(stored_reference(ckpt_path, source.rig), want)
    ckpt = torch.load(ckpt_path, weights_only=False)
    del ckpt["pattern"]
    torch.save(ckpt, tmp_path / "old.pt")
    assert stored_reference(tmp_path / "old.pt", source.rig) is None
    frame = open_source(data, "test").frames[0]
    infer(tmp_path / "old.pt", [frame.path], tmp_path / "out", progress=True, progress_bar=False)
    assert "stores no pattern" in capsys.readouterr().err
    model, _, rig = load_model(ckpt_path)
    ir = read_frame(frame.path)["ir"].astype(np.float32)
    written = OpenEXR.File(str(tmp_path / "out" / f"{frame.path.parent.name}_{frame.path.stem}.exr"),
                           separate_channels=True).channels()["disparity"].pixels
    np.testing.assert_array_equal(written, predict_disparity(model, rig, ir)[0])
    guided = predict_disparity(model, rig, ir, reference=want)[0]
    assert np.any(np.isfinite(guided) & (guided != written))  # the pattern moved some edge pixels
