"""bench.audit_probes, run as its docstring says, on the group that needs no render (the others render a
tiny scene and train a step: the integrator runs them whole)."""

import subprocess
import sys


def test_the_config_probes_all_hold():
    done = subprocess.run([sys.executable, "-m", "bench.audit_probes", "--only", "config"],
                          capture_output=True, text=True, timeout=600)
    lines = done.stdout.strip().splitlines()
    assert done.returncode == 0, done.stdout + done.stderr
    assert lines[-1].startswith(f"{len(lines) - 1} held, 0 failed of {len(lines) - 1} probes (config)")
    assert all(line.startswith("held") for line in lines[:-1]) and len(lines) > 8
