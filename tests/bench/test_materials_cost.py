"""bench.materials_cost, run as the docs run it (its own process), at a tiny size: it finds the plain way's
raw passes unchanged by the labels and normals (the timings themselves are for a quiet machine)."""

import subprocess
import sys

import pytest

pytest.importorskip("bpy")


def test_runs_tiny_and_the_data_passes_change_no_sample():
    done = subprocess.run([sys.executable, "-m", "bench.materials_cost", "--sizes", "64", "--objects", "10",
                           "--repeats", "1", "--no-lights"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    out = done.stdout
    assert "frame file, bytes: plain" in out and "materials" in out
    assert out.count("bit for bit the same") == 2
