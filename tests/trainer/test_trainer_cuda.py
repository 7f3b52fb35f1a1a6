"""The published network on a GPU: AMP training (float16 with a scaler, bfloat16) without NaNs, the loss
falling, resume on CUDA, a CUDA-written checkpoint read on CPU with the same predictions, and eval on
CUDA in reduced precision. Skipped without CUDA (`make test` is CPU-only); docs/TRAINER.md, "On a GPU",
gives the commands."""

import numpy as np
import pytest
import torch

from dotsim.dataset import read_frame
from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset
from trainer.checkpoint import load_model, predict_disparity
from trainer.config import config_from_dict, load_config
from trainer.evaluate import evaluate
from trainer.model import build_model
from trainer.samples import FrameDataset
from trainer.train import batch_loss, train

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(),
                                reason="needs a CUDA device (torch.cuda.is_available() is False)")

STEPS = 30


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """Full-resolution (1216 x 896) oracle frames: 4 scenes x 2 train frames, 1 test scene."""
    return make_dataset(tmp_path_factory.mktemp("full"), scenes=4, frames_per_scene=2, scale=1.0,
                        test_scenes=1)


def published(steps: int, amp: str):
    d = load_config("dotsim/configs/train_gigadepth.toml").to_dict()
    d["data"]["workers"] = 2
    # epochs: the 8 frames give 2 steps an epoch, and the published 10 epochs would stop at 20 steps
    # (the first GPU run found it)
    d["train"].update(max_steps=steps, amp=amp, checkpoint_every=10**6, image_every=10**6, epochs=10**6)
    return config_from_dict(d, "published, test length")


@pytest.fixture(autouse=True)
def exact_float32():
    """TF32 off, so CPU and CUDA float32 agree to float tolerance."""
    saved = torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32
    torch.backends.cuda.matmul.allow_tf32 = torch.backends.cudnn.allow_tf32 = False
    yield
    torch.backends.cuda.matmul.allow_tf32, torch.backends.cudnn.allow_tf32 = saved


@pytest.mark.parametrize("amp", ["float16", "bfloat16"])
def test_published_config_trains_resumes_and_moves_to_cpu(data, tmp_path, amp):
    cfg = published(STEPS, amp)
    source = open_source(data, "train")
    frames, rig = source.frames, source.rig
    fixed = FrameDataset(frames[:4], rig, cfg.data, seed=0, augment=False)
    batch = {k: torch.stack([fixed[i][k] for i in range(4)]).cuda() for k in fixed[0]}

    def fixed_loss(model):
        with torch.no_grad():
            return float(batch_loss(model, batch, cfg)[0])

    torch.manual_seed(cfg.seed)
    before = fixed_loss(build_model(cfg, rig).cuda())
    first = train(published(STEPS // 2, amp), open_source(data, "train"), tmp_path, device="cuda",
                  progress=False)["losses"]
    rest = train(cfg, open_source(data, "train"), tmp_path, resume=True, device="cuda",
                 progress=False)["losses"]
    losses = first + rest
    assert len(losses) == STEPS and np.all(np.isfinite(losses)), losses
    on_cuda, _, _ = load_model(tmp_path / "checkpoint.pt", "cuda")
    assert fixed_loss(on_cuda) < before, (before, losses)

    on_cpu, _, _ = load_model(tmp_path / "checkpoint.pt", "cpu")
    ir = read_frame(open_source(data, "test").frames[0].path, channels=("ir",))["ir"].astype(np.float32)
    got = predict_disparity(on_cpu, rig, ir, "cpu")[0]
    want = predict_disparity(on_cuda, rig, ir, "cuda")[0]
    assert np.mean(np.isfinite(got) == np.isfinite(want)) > 0.999
    ok = np.isfinite(got) & np.isfinite(want)
    assert np.mean(np.abs(got[ok] - want[ok]) < 1e-2) > 0.999  # argmax ties may route a few apart


def test_eval_on_cuda_in_reduced_precision(data, tmp_path):
    train(published(2, "bfloat16"), open_source(data, "train"), tmp_path / "run", device="cuda",
          progress=False)
    rows = {}
    for precision in ("float32", "bfloat16", "float16"):
        rows[precision] = evaluate(tmp_path / "run" / "checkpoint.pt", open_source(data, "test"),
                                   tmp_path / precision,
                                   device="cuda", max_frames=1, images=1, progress=False,
                                   precision=precision)
    net = {p: next(r for r in rs if r["method"] == "network" and r["range"] == "all")
           for p, rs in rows.items()}
    assert len({r["pixels"] for r in net.values()}) == 1
    for p in ("bfloat16", "float16"):
        assert abs(net[p]["o(0.5)"] - net["float32"]["o(0.5)"]) < 0.02, net
