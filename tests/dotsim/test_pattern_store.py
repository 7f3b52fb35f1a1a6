"""The dataset's pattern: made at the projector's size (resampled from a file), stored once."""

import cv2
import numpy as np
import pytest

from dotsim.dataset import PATTERN_FILE, FormatError
from dotsim.pattern_store import make_pattern, pattern_entry, store_pattern
from dotsim.patterns import PatternError, generate_dot_pattern
from generator.config import config_from_dict


def test_store_pattern_writes_once_and_refuses_another(tmp_path):
    pattern = generate_dot_pattern(40, 30, n_dots=60, seed=1)
    path = store_pattern(tmp_path / "data", pattern)
    assert path == tmp_path / "data" / PATTERN_FILE
    stored = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # decoded independently of load_pattern
    assert stored.dtype == np.uint16
    np.testing.assert_array_equal(stored, np.round(pattern.image.astype(np.float64) * 65535))
    before = path.stat().st_mtime_ns
    assert store_pattern(tmp_path / "data", generate_dot_pattern(40, 30, n_dots=60, seed=1)) == path
    assert path.stat().st_mtime_ns == before  # a rerun keeps the file
    with pytest.raises(FormatError, match=r"pattern.png: holds another pattern \(40x30"):
        store_pattern(tmp_path / "data", generate_dot_pattern(40, 30, n_dots=60, seed=2))
    path.write_bytes(b"broken")
    with pytest.raises(FormatError, match="pattern.png: not a readable PNG image"):
        store_pattern(tmp_path / "data", pattern)
    assert pattern_entry(pattern) == {"source": "procedural", "sha256": pattern.sha256,
                                      "file": "pattern.png", "width": 40, "height": 30,
                                      "params": pattern.params}


def test_pattern_file_is_resampled_to_the_projector(tmp_path):
    big = generate_dot_pattern(614, 614, density=0.01, seed=5)
    big.save_png(tmp_path / "captured.png")
    config = config_from_dict({"pattern": {"source": "file", "path": "captured.png"}}, base_dir=tmp_path)
    pattern = make_pattern(config.pattern, 307, 307)
    assert pattern.image.shape == (307, 307)
    assert pattern.params["resampled_from"] == [614, 614]
    # Area averaging keeps the mean brightness: the projector emits the same total light.
    assert pattern.image.mean() == pytest.approx(big.image.mean(), rel=0.01)
    same = make_pattern(config.pattern, 614, 614)
    np.testing.assert_array_equal(same.image, big.image)


def test_pattern_of_another_aspect_ratio_does_not_fit_the_rig(tmp_path):
    generate_dot_pattern(400, 300, density=0.01, seed=5).save_png(tmp_path / "wide.png")
    config = config_from_dict({"pattern": {"source": "file", "path": "wide.png"}}, base_dir=tmp_path)
    assert make_pattern(config.pattern, 200, 150).image.shape == (150, 200)  # same aspect ratio: resampled
    with pytest.raises(PatternError, match=r"wide.png: pattern is 400x300 px, which does not fit the rig's "
                       r"projector of 307x307 px \(another aspect ratio\)"):
        make_pattern(config.pattern, 307, 307)
