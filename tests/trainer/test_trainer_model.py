"""The branching network: the indexed layer against a naive loop, routing, and the published size."""

import math

import pytest
import torch

from trainer.config import ModelConfig, load_config
from trainer.model import GigaDepthNet, IndexedLinear, IndexedMLP, plan_groups


def _naive_linear(weight, bias, x, idx):
    """Reference: one matrix-vector product per pixel, in a Python loop."""
    return torch.stack([weight[i] @ x[p] + bias[i] for p, i in enumerate(idx.tolist())])


@pytest.mark.parametrize("grouped", [True, False])
def test_indexed_linear_matches_naive_loop_values_and_gradients(grouped):
    torch.manual_seed(0)
    layer = IndexedLinear(tables=7, in_features=5, out_features=3, chunk=4)  # chunk < pixels: several
    x = torch.randn(11, 5, requires_grad=True)
    idx = torch.tensor([0, 6, 6, 2, 3, 0, 1, 5, 6, 4, 2])
    grad_out = torch.randn(11, 3)

    y = layer(x, idx, plan_groups(idx, force=True) if grouped else False)
    (y * grad_out).sum().backward()
    fast = (y.detach(), x.grad.clone(), layer.weight.grad.clone(), layer.bias.grad.clone())

    w = layer.weight.detach().clone().requires_grad_(True)
    b = layer.bias.detach().clone().requires_grad_(True)
    x2 = x.detach().clone().requires_grad_(True)
    y2 = _naive_linear(w, b, x2, idx)
    (y2 * grad_out).sum().backward()
    for got, want in zip(fast, (y2.detach(), x2.grad, w.grad, b.grad), strict=True):
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
    # tables no pixel chose get no gradient
    assert layer.weight.grad[[t for t in range(7) if t not in idx.tolist()]].abs().sum() == 0


def test_indexed_mlp_uses_hidden_and_output_tables():
    torch.manual_seed(1)
    mlp = IndexedMLP([4, 6, 2], hidden_tables=3, out_tables=5, chunk=100)
    x = torch.randn(9, 4)
    hidden_idx = torch.randint(0, 3, (9,))
    out_idx = torch.randint(0, 5, (9,))
    l0, l1 = mlp.layers
    h = torch.nn.functional.leaky_relu(_naive_linear(l0.weight, l0.bias, x, hidden_idx))
    want = _naive_linear(l1.weight, l1.bias, h, out_idx)
    torch.testing.assert_close(mlp(x, hidden_idx, out_idx), want)


TINY = ModelConfig(
    backbone_channels=(4, 8), backbone_kernels=(5, 3), classes=(4, 3, 2), overlaps=(0, 1, 1),
    stage_inputs=((0, 4), (2, 4), (4, 4), (0, 8)), classifier_hidden=((5,), (), (3,)),
    regressor_hidden=(4,), lines=3, regress_neighbours=1, column_padding=0.1,
)


def _count(cfg: ModelConfig) -> int:
    """Parameters from the config alone: conv (no bias) + BN affine, then the weight tables."""
    n, cin = 0, 2
    for c, k in zip(cfg.backbone_channels, cfg.backbone_kernels, strict=True):
        n, cin = n + cin * c * k * k + 2 * c, c

    def mlp(dims, hidden_tables, out_tables):
        return sum(
            (out_tables if k == len(dims) - 2 else hidden_tables) * (dims[k] * dims[k + 1] + dims[k + 1])
            for k in range(len(dims) - 1)
        )

    leaves = math.prod(cfg.classes)
    for level, (c, o) in enumerate(zip(cfg.classes, cfg.overlaps, strict=True)):
        t = cfg.lines * math.prod(cfg.classes[:level])
        n += mlp([cfg.stage_inputs[level][1], *cfg.classifier_hidden[level], c + 2 * o], t, t)
    dims = [cfg.stage_inputs[-1][1], *cfg.regressor_hidden, 1]
    return n + mlp(dims, cfg.lines * leaves // cfg.classes[-1], cfg.lines * leaves)


def test_parameter_count_tiny_and_published_on_meta_device():
    assert sum(p.numel() for p in GigaDepthNet(TINY, rows=6).parameters()) == _count(TINY)
    published = load_config("dotsim/configs/train_gigadepth.toml").model
    with torch.device("meta"):
        net = GigaDepthNet(published, rows=448)
    n = sum(p.numel() for p in net.parameters())
    assert n == _count(published)
    assert 340e6 < n < 420e6, n  # "about 380 M parameters"


def test_forward_routes_to_leaf_and_shapes():
    """With tree weights set by hand, hard routing must land in the leaf whose classifier says so."""
    torch.manual_seed(2)
    net = GigaDepthNet(TINY, rows=6).eval()
    with torch.no_grad():
        for mlp in [*net.classifiers, net.regressor]:
            for layer in mlp.layers:
                layer.weight.zero_()
                layer.bias.zero_()
        # level 1 picks class 2, level 2 local argmax 3 (-> child 2*3 + 3 - 1 = 8), level 3 local 0
        # (-> leaf 8*2 + 0 - 1 = 15); regressor offset 0.25 from the output bias of leaf 15, line 0..2
        net.classifiers[0].layers[-1].bias[:, 2] = 1.0
        net.classifiers[1].layers[-1].bias[:, 3] = 1.0
        net.classifiers[2].layers[-1].bias[:, 0] = 1.0
        net.regressor.layers[-1].bias[[15, 24 + 15, 48 + 15], 0] = 0.25
    col = net(torch.rand(2, 1, 12, 10))
    assert col.shape == (2, 6, 5)
    want = ((15 + 0.25) / 24 - 0.1) / 0.8
    torch.testing.assert_close(col, torch.full_like(col, want))


def test_pixel_lines_follow_crop_offset():
    net = GigaDepthNet(TINY, rows=6)
    lines = net.pixel_lines(torch.tensor([0, 2]), h=4, w=1).reshape(2, 4)
    # rows 0..3 and 2..5 of 6 half-res rows onto 3 lines: row * 3 // 6
    assert lines.tolist() == [[0, 0, 1, 1], [1, 1, 2, 2]]


def test_loss_terms_teacher_forcing_targets():
    """A pixel whose GT is exactly in leaf 5 with offset 0.5: CE targets per level and L1 targets."""
    torch.manual_seed(3)
    net = GigaDepthNet(TINY, rows=6)
    feat = torch.randn(1, 8, 1, 1)
    padded = (5 + 0.5) / 24
    column = torch.tensor([[[(padded - 0.1) / 0.8]]])
    terms = net.loss_terms(feat, torch.tensor([0]), column, torch.ones(1, 1, 1, dtype=torch.bool))
    x = feat[0, :, 0, 0]
    line0 = torch.tensor([0])
    f = torch.nn.functional
    # level 1: leaf 5 -> class 5 // 6 = 0
    l1 = net.classifiers[0](x[None, 0:4], line0, line0)
    torch.testing.assert_close(terms["ce"][0], f.cross_entropy(l1, torch.tensor([0]), reduction="none"))
    # level 2: child 5 // 2 = 2 of parent 0 (local 2 + overlap 1 = 3); neighbour parent 1 sees child 2 as
    # local 2 - 3 + 1 = 0 (within its overlap); parent -1 does not exist
    want = 0
    for parent, target in ((0, 3), (1, 0)):
        logits = net.classifiers[1](x[None, 2:6], torch.tensor([parent]), torch.tensor([parent]))
        want = want + f.cross_entropy(logits, torch.tensor([target]), reduction="none")
    torch.testing.assert_close(terms["ce"][1], want)
    # regressor: leaves 4, 5, 6 with targets 1.5, 0.5, -0.5
    want = 0
    for leaf, target in ((4, 1.5), (5, 0.5), (6, -0.5)):
        out = net.regressor(x[None, 0:8], torch.tensor([leaf // 2]), torch.tensor([leaf]))[:, 0]
        want = want + (out - target).abs()
    torch.testing.assert_close(terms["l1"], want)


def test_loss_terms_of_many_pixels_equal_each_pixel_alone():
    """All pixels (every line, leaves at both ends of the tree, some masked) in one call give the terms
    each pixel gets alone, gradients included: the batched neighbour pairs keep pixels apart."""
    torch.manual_seed(4)
    net = GigaDepthNet(TINY, rows=6)
    feat = torch.randn(2, 8, 6, 5, requires_grad=True)
    column = torch.rand(2, 6, 5)
    column[0, 0, :2] = torch.tensor([0.0, 1.0])  # leaves 2 and 21 of 24 after padding: tree ends near
    valid = torch.rand(2, 6, 5) > 0.2
    row0 = torch.tensor([0, 0])
    terms = net.loss_terms(feat, row0, column, valid)
    total = sum(ce.sum() for ce in terms["ce"]) + terms["l1"].sum()
    grads = torch.autograd.grad(total, [feat, *net.parameters()], allow_unused=True)
    want_ce, want_l1, want_total = [[] for _ in TINY.classes], [], 0
    for b, i, j in valid.nonzero().tolist():
        one = torch.zeros_like(valid)
        one[b, i, j] = True
        alone = net.loss_terms(feat, row0, column, one)
        for level, ce in enumerate(alone["ce"]):
            want_ce[level].append(ce)
        want_l1.append(alone["l1"])
        want_total = want_total + sum(ce.sum() for ce in alone["ce"]) + alone["l1"].sum()
    for level, ce in enumerate(terms["ce"]):
        torch.testing.assert_close(ce, torch.cat(want_ce[level]))
    torch.testing.assert_close(terms["l1"], torch.cat(want_l1))
    want_grads = torch.autograd.grad(want_total, [feat, *net.parameters()], allow_unused=True)
    for got, want in zip(grads, want_grads, strict=True):
        if want is None:
            assert got is None or not got.any()
        else:
            torch.testing.assert_close(got, want)
