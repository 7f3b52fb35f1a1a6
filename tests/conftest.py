"""Fixtures shared by test modules in several folders (tests/trainer/ and tests/dotsim/)."""

import pytest
import torch

from tests.trainer_fixtures import make_dataset


@pytest.fixture(scope="module")
def one_thread():
    """One intra-op thread: on the shared 2-core machine two threads measured 3-10x slower per step."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A tiny oracle dataset (tests/trainer_fixtures.py): 3 train scenes and 1 test scene of 2 frames.
    Modules that need another size define their own `data`."""
    return make_dataset(tmp_path_factory.mktemp("ds"), scenes=3, frames_per_scene=2, test_scenes=1)
