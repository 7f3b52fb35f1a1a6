"""bench.rgb_cost, run as the docs run it (its own process), at a tiny size: it reports each way against
the plain one and finds the plain way's raw passes unchanged by the colour camera (the timings themselves
are for a quiet machine)."""

import subprocess
import sys

import pytest

pytest.importorskip("bpy")


def test_runs_tiny_and_the_colour_camera_changes_no_ir_sample():
    done = subprocess.run([sys.executable, "-m", "bench.rgb_cost", "--sizes", "64", "--objects", "10",
                           "--repeats", "1"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    out = done.stdout
    assert "IR 64 x 36, colour 96 x 54" in out and "frame file, bytes: plain" in out and "rgb_16" in out
    assert out.count("bit for bit the same") == 2
