"""bench.exr_readability, run as the docs say (its own process, so that OpenCV's EXR codec is on), on a
small real dataset: the readers' verdicts that docs/results/exr_compression.md reports."""

import json
import subprocess
import sys

from dotsim.oracle_dataset import make_dataset


def test_the_readers_verdicts_and_sizes(tmp_path):
    data = make_dataset(tmp_path / "data", scenes=1, frames_per_scene=2, ir_bits=10)
    out = tmp_path / "rows.json"
    subprocess.run([sys.executable, "-m", "bench.exr_readability", "--data", str(data), "--frames", "2",
                    "--repeats", "1", "--json", str(out)], check=True, capture_output=True)
    rows = {(row["compression"], row["names"]): row for row in json.loads(out.read_text())}
    assert {c for c, _ in rows} == {"zstd", "zip", "piz"} and len(rows) == 9
    for (compression, names), row in rows.items():
        assert row["OpenEXR"] == "all" and row["bytes"] > 0 and row["encode_s"] >= 0
        plain_y = names.startswith("IR as Y") and compression != "zstd"
        assert row["cv2"] == ("ir" if plain_y else "no"), (compression, names)
        assert (row["imageio"] != "no") == plain_y, (compression, names)
    assert rows[("zstd", "as stored")]["bytes"] < rows[("zip", "as stored")]["bytes"]
