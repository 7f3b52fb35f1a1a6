"""[train] optimizer = "lazy_adam": Adam on the weight-table rows a batch used, against torch's own Adam
and SparseAdam, and a run of the tiny network with it."""

import pytest
import torch

from dotsim.config_schema import ConfigError
from dotsim.frame_source import open_source
from tests.trainer_fixtures import tiny_config
from trainer.model import IndexedLinear, plan_groups
from trainer.train import LazyAdam, train

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py


def _loss(layer: IndexedLinear, dense: torch.nn.Parameter, x: torch.Tensor, idx: torch.Tensor):
    return layer(x, idx, plan_groups(idx)).square().sum() + (dense * x.mean()).square().sum()


def _steps(layer: IndexedLinear, dense: torch.nn.Parameter, opt, batches) -> None:
    """Optimiser steps of `layer` and a dense parameter beside it (as the backbone is), one per batch of
    (pixels' inputs, their tables)."""
    for x, idx in batches:
        opt.zero_grad(set_to_none=True)
        _loss(layer, dense, x, idx).backward()
        opt.step()


def _pair(seed: int = 0) -> tuple[IndexedLinear, torch.nn.Parameter]:
    torch.manual_seed(seed)
    return IndexedLinear(tables=6, in_features=4, out_features=3), torch.nn.Parameter(torch.randn(5))


def _copy(layer: IndexedLinear, dense: torch.nn.Parameter) -> tuple[IndexedLinear, torch.nn.Parameter]:
    twin, twin_dense = _pair()
    twin.load_state_dict(layer.state_dict())
    with torch.no_grad():
        twin_dense.copy_(dense)
    return twin, twin_dense


def test_lazy_adam_is_adam_when_every_row_is_used():
    """With every table row used by every batch, updating only the rows used is Adam: torch.optim.Adam
    on dense gradients gives the same parameters."""
    torch.manual_seed(3)
    batches = [(torch.randn(30, 4), torch.arange(30) % 6) for _ in range(5)]
    layer, dense = _pair()
    reference, reference_dense = _copy(layer, dense)
    layer.sparse_grad = True
    _steps(layer, dense, LazyAdam([*layer.parameters(), dense], lr=0.01), batches)
    _steps(reference, reference_dense,
           torch.optim.Adam([*reference.parameters(), reference_dense], lr=0.01), batches)
    pairs = ((layer.weight, reference.weight), (layer.bias, reference.bias), (dense, reference_dense))
    for got, want in pairs:
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)


def test_lazy_adam_moves_only_the_rows_used_as_sparse_adam_does():
    """Rows no batch used keep their values exactly (Adam would move them on their momentum); the rows
    used follow torch.optim.SparseAdam on the same sparse gradients; the dense parameter follows Adam."""
    torch.manual_seed(4)
    tables = [torch.tensor([0, 2, 2, 5]), torch.tensor([2, 5, 5, 5]), torch.tensor([0, 0, 2, 2])]
    batches = [(torch.randn(4, 4), t) for t in tables]  # rows 1, 3 never used; 0 and 5 skip a step
    layer, dense = _pair()
    start = layer.weight.detach().clone()
    sparse_ref, dense_ref = _copy(layer, dense)
    layer.sparse_grad = sparse_ref.sparse_grad = True
    _steps(layer, dense, LazyAdam([*layer.parameters(), dense], lr=0.01), batches)

    tables_opt = torch.optim.SparseAdam(list(sparse_ref.parameters()), lr=0.01)
    dense_opt = torch.optim.Adam([dense_ref], lr=0.01)
    for x, idx in batches:
        tables_opt.zero_grad(set_to_none=True)
        dense_opt.zero_grad(set_to_none=True)
        _loss(sparse_ref, dense_ref, x, idx).backward()
        tables_opt.step()
        dense_opt.step()

    torch.testing.assert_close(layer.weight[[1, 3]], start[[1, 3]], rtol=0, atol=0)
    for got, want in ((layer.weight, sparse_ref.weight), (layer.bias, sparse_ref.bias), (dense, dense_ref)):
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
    assert not torch.equal(layer.weight[[0, 2, 5]], start[[0, 2, 5]])


def test_lazy_adam_trains_and_resumes_identically(data, tmp_path):
    """The tiny network with lazy_adam: the loss falls, and 3 steps + a resume for 3 more (the moments
    and step counts of the rows used saved and read back) are the 6 unbroken steps."""
    cfg = dict(optimizer="lazy_adam", lr=0.01)
    straight = train(tiny_config(6, **cfg), open_source(data, "train"), tmp_path / "a", progress=False)
    first = train(tiny_config(3, **cfg), open_source(data, "train"), tmp_path / "b", progress=False)
    rest = train(tiny_config(6, **cfg), open_source(data, "train"), tmp_path / "b", resume=True,
                 progress=False)
    assert first["losses"] + rest["losses"] == straight["losses"]
    plain = train(tiny_config(6, optimizer="adam", lr=0.01), open_source(data, "train"), tmp_path / "c",
                  progress=False)["losses"]
    assert straight["losses"][0] == plain[0] and straight["losses"] != plain  # another optimiser from step 2
    long = train(tiny_config(20, **cfg), open_source(data, "train"), tmp_path / "d", progress=False)["losses"]
    assert sum(long[-5:]) < 0.9 * sum(long[:5])


def test_lazy_adam_with_weight_decay_is_refused():
    with pytest.raises(ConfigError, match=r"\[train\] weight_decay.*lazy_adam"):
        tiny_config(2, optimizer="lazy_adam", weight_decay=1e-5)
