"""Output folders a command cannot use (read-only, missing, full), and what a failed write may leave:
helpers for the tests of every command that writes (the fixtures built on them: tests/conftest.py)."""

from __future__ import annotations

import contextlib
import os
import subprocess
from pathlib import Path

import pytest

from dotsim import file_io


@contextlib.contextmanager
def read_only(folder: Path):
    """`folder` (and all in it) read-only while the block runs: a read-only bind mount over it when
    this runs as root (root writes through a chmod-ed folder), else its folders chmod-ed to r-x."""
    if os.geteuid() == 0:
        done = subprocess.run(["mount", "--bind", "-o", "ro", str(folder), str(folder)], capture_output=True,
                              text=True)
        if done.returncode != 0:
            pytest.skip(f"cannot bind-mount {folder} read-only here: {done.stderr.strip()}")
        try:
            yield folder
        finally:
            subprocess.run(["umount", str(folder)], check=True)
        return
    folders = [folder, *(p for p in folder.rglob("*") if p.is_dir())]
    for path in folders:
        path.chmod(0o555)
    try:
        yield folder
    finally:
        for path in folders:
            path.chmod(0o755)


def leftovers(root: Path) -> list[Path]:
    """Half-written files under root: the atomic writer's temporaries."""
    return sorted(p for p in Path(root).rglob("*") if p.name.startswith(file_io.TMP_PREFIX))


def assert_one_line_error(err: str, *names: object) -> None:
    """A command's stderr: one error line (besides a progress bar's, redrawn with carriage returns),
    no traceback, naming each of `names`."""
    lines = [line for line in err.split("\n") if line and "\r" not in line]
    assert len(lines) == 1 and "Traceback" not in err and ": error: " in lines[0], err
    for name in names:
        assert str(name) in lines[0], (name, err)


def snapshot(root: Path) -> dict[str, bytes | None]:
    """Every path under root (relative, as text) with its bytes (None for a folder): equal snapshots
    mean nothing was added, removed or changed."""
    root = Path(root)
    return {str(p.relative_to(root)): None if p.is_dir() else p.read_bytes() for p in sorted(root.rglob("*"))}
