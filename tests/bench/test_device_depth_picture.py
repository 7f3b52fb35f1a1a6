"""bench/device_depth_picture.py: its summary's doctest, run as its own process (the picture itself is
drawn from a rendered dataset, docs/DEVICE_DEPTH.md)."""

import subprocess
import sys


def test_doctests():
    done = subprocess.run([sys.executable, "-m", "doctest", "-v", "bench/device_depth_picture.py"],
                          capture_output=True, text=True)
    assert done.returncode == 0 and "passed and 0 failed" in done.stdout, done.stdout[-2000:] + done.stderr
