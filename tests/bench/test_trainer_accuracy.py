"""bench.trainer_accuracy's dry run with two test sets: a disjoint-mesh and a seen-mesh one (new scenes of
the training meshes, as DepthInSpace tests), each evaluated and reported with its goals."""

import pytest

from bench.trainer_accuracy import main
from tests.trainer_fixtures import make_dataset


@pytest.mark.usefixtures("one_thread")
def test_both_test_sets_are_evaluated_and_reported(tmp_path, capsys):
    data = make_dataset(tmp_path / "ds", scenes=2, frames_per_scene=2, test_scenes=1, seed=7)
    seen = make_dataset(tmp_path / "seen", scenes=0, frames_per_scene=2, test_scenes=1, seed=8)
    out = tmp_path / "bench"
    assert main(["--data", str(data), "--seen-test-data", str(seen), "--config", "train_tiny",
                 "--minutes", "0.01", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "test split, disjoint meshes:" in text and "test split, seen meshes:" in text
    assert text.count("network o(0.5)") == 2
    assert "test, seen meshes: 1 scenes (2 frames)" in text
    assert (out / "eval" / "eval.md").is_file() and (out / "eval_seen" / "eval.md").is_file()
