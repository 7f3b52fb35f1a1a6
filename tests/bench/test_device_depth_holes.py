"""bench/device_depth_holes.py: its doctests (each cause's rule on a hand-made example: the left band and
border, the band a near box hides from the right camera, a depth edge, a block without dots or
contrast, the shares and errors), run as its own process (the table and the picture come from rendered
tabletop scenes, docs/DEVICE_DEPTH.md)."""

import subprocess
import sys


def test_doctests():
    done = subprocess.run([sys.executable, "-m", "doctest", "-v", "bench/device_depth_holes.py"],
                          capture_output=True, text=True)
    assert done.returncode == 0 and "passed and 0 failed" in done.stdout, done.stdout[-2000:] + done.stderr
