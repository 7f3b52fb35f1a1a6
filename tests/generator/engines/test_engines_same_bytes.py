"""Every engine writes the same bytes (issue 28): the same tiny scenes rendered through the local
pool with one worker and with two, and through Ray (the one-machine cluster `--ray local` starts),
give files of equal sha256, frames and all. Slurm's array against a local run: test_slurm.py
(it needs a one-node Slurm started as root)."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from generator.config import load_config
from generator.driver import run
from generator.engines.local_pool import LocalExecutor
from generator.engines.ray_cluster import RayExecutor
from generator.engines.steps import RUN_FILE
from generator.run_request import RunRequest

TINY = Path(__file__).resolve().parents[3] / "dotsim" / "configs" / "tiny.toml"
SCENES = 3  # tiny.toml: two scenes per shard, so the run spans two shards
SEED = 11


def file_hashes(root: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file of a dataset, read here (not the checksums the dataset
    records), logs and the writer lock aside."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*"))
            if p.is_file() and p.relative_to(root).parts[0] != "logs" and not p.name.startswith(".")}


def render(out: Path, executor) -> dict[str, str]:
    summary = run(RunRequest(load_config(TINY), out, "train", SCENES, seed=SEED, executor=executor,
                             progress=False))
    assert (summary.done, summary.failed) == (SCENES, []), summary.line()
    return file_hashes(out)


@pytest.fixture(scope="module")
def one_worker(tmp_path_factory) -> dict[str, str]:
    hashes = render(tmp_path_factory.mktemp("engines") / "one", LocalExecutor(1))
    frames = [name for name in hashes if name.endswith(".exr")]
    assert len(frames) == SCENES * 4 and RUN_FILE in hashes, sorted(hashes)
    return hashes


def test_two_local_workers_write_the_bytes_of_one(one_worker, tmp_path):
    assert render(tmp_path / "two", LocalExecutor(2)) == one_worker


def test_ray_writes_the_bytes_of_the_local_pool(one_worker, tmp_path, monkeypatch):
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    executor = RayExecutor("local", local_workers=2)
    try:
        assert render(tmp_path / "ray", executor) == one_worker
    finally:
        executor.close()
