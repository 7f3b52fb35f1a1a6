"""Mixed precision and devices, run for real on CPU: the indexed layers under autocast, float16 (with a
gradient scaler) and bfloat16 training with checkpoint and resume, reduced-precision inference against
float32, and checkpoints read on every available device (CPU alone here; tests/trainer/test_trainer_cuda.py
adds the GPU)."""

import numpy as np
import pytest
import torch

from dotsim.dataset import read_frame
from dotsim.frame_source import open_source
from tests.trainer.test_trainer_model import _naive_linear
from tests.trainer_fixtures import tiny_config
from trainer.checkpoint import load_checkpoint, load_model, predict_disparity
from trainer.config import config_from_dict
from trainer.model import IndexedLinear, autocast, build_model, plan_groups
from trainer.samples import FrameDataset
from trainer.train import batch_loss, train

LOW = [torch.bfloat16, torch.float16]
DEVICES = ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])
pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def fixed_batch(data, cfg):
    source = open_source(data, "train")
    frames, rig = source.frames, source.rig
    fixed = FrameDataset(frames[:4], rig, cfg.data, seed=0, augment=False)
    return {k: torch.stack([fixed[i][k] for i in range(4)]) for k in fixed[0]}, rig


@pytest.mark.parametrize("grouped", [True, False])
@pytest.mark.parametrize("dtype", LOW, ids=str)
def test_indexed_linear_under_autocast_computes_in_the_input_precision(grouped, dtype):
    """Values and gradients against a float64 loop; weight gradients stay float32."""
    torch.manual_seed(0)
    layer = IndexedLinear(tables=7, in_features=16, out_features=8, chunk=4)
    x = torch.randn(11, 16).to(dtype).requires_grad_(True)  # as the backbone hands it over
    idx = torch.tensor([0, 6, 6, 2, 3, 0, 1, 5, 6, 4, 2])
    grad_out = torch.randn(11, 8)
    with autocast("cpu", str(dtype).removeprefix("torch.")):
        y = layer(x, idx, plan_groups(idx, force=True) if grouped else False)
    assert y.dtype == dtype
    (y.float() * grad_out).sum().backward()
    assert x.grad.dtype == dtype and layer.weight.grad.dtype == layer.bias.grad.dtype == torch.float32

    w, b = (p.detach().double().requires_grad_(True) for p in (layer.weight, layer.bias))
    x64 = x.detach().double().requires_grad_(True)
    y64 = _naive_linear(w, b, x64, idx)
    (y64 * grad_out.double()).sum().backward()
    tol = {"rtol": 0.02, "atol": 0.03} if dtype == torch.bfloat16 else {"rtol": 3e-3, "atol": 3e-3}
    for got, want in ((y, y64), (x.grad, x64.grad), (layer.weight.grad, w.grad), (layer.bias.grad, b.grad)):
        torch.testing.assert_close(got.double(), want.detach(), **tol)


@pytest.mark.parametrize("precision", ["bfloat16", "float16"])
def test_loss_and_column_are_float32_under_autocast(data, precision):
    """The low precision stays inside the network: in bfloat16, a column of 128 leaves would keep a
    quarter of a leaf near the end of the tree, so the offset is added in float32."""
    cfg = tiny_config(1)
    batch, rig = fixed_batch(data, cfg)
    torch.manual_seed(0)
    model = build_model(cfg, rig).eval()
    with torch.no_grad():
        full = model(batch["ir"], batch["row0"])
        with autocast("cpu", precision):
            low = model(batch["ir"], batch["row0"])
            loss, _ = batch_loss(model, batch, cfg)
    assert loss.dtype == low.dtype == torch.float32 and torch.isfinite(loss)
    leaves = model.leaves * (1 - 2 * cfg.model.column_padding)
    err = ((low - full).abs() * leaves)[(low - full).abs() * leaves < 0.5]  # same leaf
    assert err.numel() > 0.9 * low.numel()
    assert float(err.max()) < 0.05, float(err.max())


def test_older_boolean_amp_reads_as_a_precision():
    assert config_from_dict({"train": {"amp": True}}).train.amp == "float16"
    assert config_from_dict({"train": {"amp": False}}).train.amp == "off"


@pytest.mark.parametrize("precision", ["bfloat16", "float16"])
def test_amp_training_on_cpu_lowers_the_loss_and_resumes_exactly(data, tmp_path, precision):
    steps = 20
    cfg = tiny_config(steps, lr=0.01, amp=precision)
    batch, rig = fixed_batch(data, cfg)

    def fixed_loss(model):
        with torch.no_grad():
            return float(batch_loss(model, batch, cfg)[0])

    torch.manual_seed(cfg.seed)
    before = fixed_loss(build_model(cfg, rig))
    straight = train(cfg, open_source(data, "train"), tmp_path / "a", progress=False)["losses"]
    assert np.all(np.isfinite(straight))
    ckpt, _, _ = load_checkpoint(tmp_path / "a" / "checkpoint.pt")
    model = build_model(cfg, rig)
    model.load_state_dict(ckpt["model"])
    after = fixed_loss(model)
    assert after < 0.95 * before, (before, after)
    if precision == "float16":  # the scaler's state travels with the checkpoint
        assert ckpt["scaler"]["scale"] > 0 and ckpt["scaler"]["_growth_tracker"] == steps
    else:
        assert ckpt["scaler"] == {}
    first = train(tiny_config(steps // 2, lr=0.01, amp=precision), open_source(data, "train"), tmp_path / "b",
                  progress=False)["losses"]
    rest = train(cfg, open_source(data, "train"), tmp_path / "b", resume=True, progress=False)["losses"]
    assert first + rest == straight


@pytest.fixture(scope="module")
def checkpoint(data, tmp_path_factory):
    """A tiny network trained for 20 float32 steps (enough to route pixels over many leaves)."""
    run = tmp_path_factory.mktemp("run")
    train(tiny_config(20, lr=0.01), open_source(data, "train"), run, progress=False)
    return run / "checkpoint.pt"


def test_reduced_precision_inference_agrees_with_float32(data, checkpoint):
    """Disparity differences of float16 / bfloat16 autocast against float32, on the test frames
    (the figures docs/TRAINER.md quotes come from bench.trainer_gpu --device cpu --small)."""
    frames = open_source(data, "test").frames
    model, _, rig = load_model(checkpoint)
    for precision, median_px in (("float16", 0.01), ("bfloat16", 0.1)):
        diffs = []
        for f in frames:
            ir = read_frame(f.path, channels=("ir",))["ir"].astype(np.float32)
            full = predict_disparity(model, rig, ir)[0]
            low = predict_disparity(model, rig, ir, precision=precision)[0]
            both = np.isfinite(full) & np.isfinite(low)
            assert both.sum() > 0.95 * np.isfinite(full).sum()
            diffs.append(np.abs(low - full)[both])
        d = np.concatenate(diffs)
        assert np.median(d) < median_px, (precision, np.median(d))


@pytest.mark.parametrize("device", DEVICES)
def test_checkpoint_loads_on_every_device_with_the_same_predictions(data, checkpoint, device):
    """load_model reads to CPU and moves the network: the same path a CUDA-written checkpoint takes
    onto a CPU-only machine. Predictions on `device` equal the CPU's to float tolerance."""
    model, _, rig = load_model(checkpoint, device)
    assert {p.device.type for p in [*model.parameters(), *model.buffers()]} == {device}
    reference, _, _ = load_model(checkpoint, "cpu")
    frames = open_source(data, "test").frames
    ir = read_frame(frames[0].path, channels=("ir",))["ir"].astype(np.float32)
    got, want = predict_disparity(model, rig, ir, device)[0], predict_disparity(reference, rig, ir)[0]
    np.testing.assert_array_equal(np.isfinite(got), np.isfinite(want))
    ok = np.isfinite(want)
    assert np.mean(np.abs(got[ok] - want[ok]) < 1e-3) > 0.999
