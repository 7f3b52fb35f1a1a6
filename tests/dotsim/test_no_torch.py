"""The core (dotsim/) is numpy only: importing every one of its modules loads no torch, so reading and
writing datasets and shards needs no deep-learning stack (the trainer's torch datasets live in
trainer/samples.py)."""

from __future__ import annotations

import subprocess
import sys


def test_importing_every_core_module_loads_no_torch():
    code = ("import importlib, pkgutil, sys, dotsim\n"
            "names = [m.name for m in pkgutil.walk_packages(dotsim.__path__, 'dotsim.')]\n"
            "for name in names:\n"
            "    importlib.import_module(name)\n"
            "print(len(names), 'torch' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    count, loaded = out.split()
    assert int(count) > 30 and loaded == "False"
