"""bench.materials_cost runs at a tiny size and finds the plain way's raw passes unchanged by the labels
and normals (the timings themselves are the integrator's, on a quiet machine)."""

import pytest

from bench import materials_cost

pytest.importorskip("bpy")


def test_runs_tiny_and_the_data_passes_change_no_sample(capsys):
    assert materials_cost.main(["--sizes", "64", "--objects", "10", "--repeats", "1", "--no-lights"]) == 0
    out = capsys.readouterr().out
    assert "frame file, bytes: plain" in out and "materials" in out
    assert out.count("bit for bit the same") == 2
