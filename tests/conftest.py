"""Fixtures shared by test modules in several folders (tests/trainer/, tests/dotsim/, tests/commands/,
tests/capture/)."""

import errno
import os

import pytest
import torch

from dotsim import file_io
from dotsim.oracle_dataset import make_dataset
from tests.output_folders import read_only


@pytest.fixture(scope="module")
def one_thread():
    """One intra-op thread: on the shared 2-core machine two threads measured 3-10x slower per step."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A tiny oracle dataset (dotsim/oracle_dataset.py): 3 train scenes and 1 test scene of 2 frames.
    Modules that need another size define their own `data`."""
    return make_dataset(tmp_path_factory.mktemp("ds"), scenes=3, frames_per_scene=2, test_scenes=1)


@pytest.fixture
def read_only_folder(tmp_path):
    """An empty folder nothing can be written in (`read_only`)."""
    folder = tmp_path / "read_only"
    folder.mkdir()
    with read_only(folder):
        yield folder


@pytest.fixture
def no_space(monkeypatch):
    """Every file the atomic writer finishes runs out of space when its data reaches the disk (the
    ENOSPC fsync reports on a full filesystem), so a command meets a full disk in its real write path.
    """
    def full(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(file_io.os, "fsync", full)
