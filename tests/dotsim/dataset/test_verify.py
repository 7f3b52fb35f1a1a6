"""dotsim.dataset.verify: what repair does with a file verify flags (issue 37, item 5), through the
command as a user runs it, on a real sealed dataset."""

from __future__ import annotations

import json

from commands.cli import main
from dotsim.oracle_dataset import make_dataset


def test_repair_never_seals_a_file_verify_flags_as_unlisted(tmp_path, capsys):
    data = make_dataset(tmp_path / "data", scenes=1, frames_per_scene=1)
    index_before = (data / "index.json").read_bytes()
    (data / "notes.txt").write_text("dropped in after the seal")
    assert main(["verify", str(data)]) == 1
    out = capsys.readouterr().out
    assert f"{data / 'notes.txt'}: not listed in index.json" in out
    assert main(["verify", str(data), "--repair"]) == 1
    captured = capsys.readouterr()
    assert "repair: not sealed" in captured.err
    assert (data / "index.json").read_bytes() == index_before  # the seal does not vouch for it
    assert "notes.txt" not in json.loads(index_before)["files"]
    assert main(["verify", str(data)]) == 1  # still flagged, until it is moved out
    (data / "notes.txt").unlink()
    capsys.readouterr()
    assert main(["verify", str(data)]) == 0
