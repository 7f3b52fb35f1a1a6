"""The entry script as the pipeline runs it: a separate process, JSON specs in, raw .npz out."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dotsim.patterns import generate_dot_pattern
from dotsim.rig.presets import get_preset
from generator.blender import demo_scenes as ds
from generator.blender.frame_recipe import RAW_PASSES

pytest.importorskip("bpy")
SCRIPT = Path(__file__).resolve().parents[3] / "generator" / "blender" / "run_in_blender.py"


def test_run_in_blender_writes_raw_npz_and_reports_bad_specs(tmp_path):
    rig = get_preset("structure_core").scaled(0.1)
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, seed=1)
    pattern.save_png(tmp_path / "pattern.png")
    moved = np.eye(4)
    moved[2, 3] = -0.5
    spec = ds.base_spec(
        rig.to_dict(),
        str(tmp_path / "pattern.png"),
        pattern.sha256,
        poses=[np.eye(4).tolist(), moved.tolist()],
    )
    spec["objects"] = [ds.wall(1.5)]
    (tmp_path / "scene_0000003.json").write_text(json.dumps(spec))
    bad = dict(spec, pattern={"path": str(tmp_path / "missing.png"), "sha256": "x"})
    (tmp_path / "scene_0000004.json").write_text(json.dumps(bad))
    out = tmp_path / "out"
    # Run from elsewhere: the script must find the repository by itself, as inside Blender.
    proc = subprocess.run(
        [
            sys.executable,
            str(SCRIPT),
            "--",
            str(tmp_path / "scene_0000003.json"),
            str(tmp_path / "scene_0000004.json"),
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=300,
    )
    assert proc.returncode == 1, proc.stderr
    assert "missing.png" in proc.stderr and "1 of 2 specs rendered" in proc.stdout
    assert sorted(p.name for p in out.iterdir()) == ["scene_0000003_raw.npz"]  # no temp files left
    with np.load(out / "scene_0000003_raw.npz") as raw:
        assert sorted(raw.files) == sorted(
            f"{name}_{k}" for name in RAW_PASSES for k in range(2)
        )
        np.testing.assert_allclose(raw["depth_0"], 1.5, rtol=1e-6)
        np.testing.assert_allclose(raw["depth_1"], 2.0, rtol=1e-6)
        assert raw["projector_0"].dtype == np.float32
        assert raw["projector_0"].shape == (rig.camera.height, rig.camera.width)
