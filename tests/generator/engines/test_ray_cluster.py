"""`dotsim generate --ray` on a real Ray cluster on this machine (tiny scenes): two nodes, one removed
mid-run, output byte-identical to a local run; and bad input (no ray, no head at the address, an
output folder a node cannot see) stopping with one line before anything is written."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import ray
from ray.cluster_utils import Cluster

from dotsim import dataset
from generator.config import ConfigError, load_config
from generator.driver import generate
from generator.engines.one_node_slurm import free_port
from generator.engines.ray_cluster import RayExecutor
from tests.generator.test_generate import TINY, run_cli

SEED = 5
SCENES = 6
NODE = dict(num_cpus=1, object_store_memory=80 * 2**20)


def tree_bytes(root: Path) -> dict[str, bytes]:
    """Every file of a dataset (relative path -> bytes), logs aside."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.relative_to(root).parts[0] != "logs"}


@pytest.fixture(scope="module")
def local_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("ray") / "local"
    summary = generate(load_config(TINY), out, "train", SCENES, seed=SEED, progress=False)
    assert summary.done == SCENES
    return out


@pytest.fixture
def cluster(monkeypatch):
    monkeypatch.setenv("RAY_USAGE_STATS_ENABLED", "0")
    cluster = Cluster(initialize_head=True, head_node_args=dict(NODE, include_dashboard=False))
    yield cluster
    if ray.is_initialized():
        ray.shutdown()
    cluster.shutdown()


def test_two_nodes_one_removed_mid_run_same_bytes_as_local(cluster, local_run, tmp_path):
    worker = cluster.add_node(**NODE)
    cluster.wait_for_nodes()
    out = tmp_path / "ray"
    removed_at = []

    def remove_worker_after_first_scene():
        while not dataset.complete_scenes(out):
            time.sleep(0.05)
        # Both nodes' CPUs taken: the worker node is in the middle of a task when it dies.
        removed_at.append((len(dataset.complete_scenes(out)), ray.available_resources().get("CPU", 0)))
        cluster.remove_node(worker, allow_graceful=False)

    remover = threading.Thread(target=remove_worker_after_first_scene, daemon=True)
    remover.start()
    backend = RayExecutor(cluster.address, scenes_per_task=2)
    try:
        summary = generate(load_config(TINY), out, "train", SCENES, seed=SEED, progress=False,
                           executor=backend)
    finally:
        backend.close()
    remover.join(timeout=60)
    assert removed_at and removed_at[0][0] < SCENES and removed_at[0][1] == 0, removed_at
    assert (summary.done, summary.failed) == (SCENES, [])
    assert [s.scene_index for s in dataset.open_dataset(out).scenes] == list(range(SCENES))
    assert not list(out.rglob(dataset.TMP_PREFIX + "*"))  # the dead node's half scene is gone
    assert tree_bytes(out) == tree_bytes(local_run)


def test_unreachable_address_is_one_line_and_writes_nothing(tmp_path, capsys):
    out = tmp_path / "never"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "1",
                   "--ray", f"127.0.0.1:{free_port()}") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no Ray head answers" in err and "ray start --head" in err
    assert not out.exists()


def test_missing_ray_names_the_extra(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    out = tmp_path / "never"
    assert run_cli("--config", str(TINY), "--out", str(out), "--split", "train", "--scenes", "1",
                   "--ray", "local") == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and 'pip install "dotsim[ray]"' in err
    assert not out.exists()


def test_output_folder_a_node_cannot_see(cluster, tmp_path):
    """A node whose processes see another filesystem at --out's path (a private mount namespace with
    an empty tmpfs there) is found by the marker check; nothing is left in --out."""
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        pytest.skip("needs root and unshare to give one Ray node its own view of the filesystem")
    shared = tmp_path / "shared"
    shared.mkdir()
    ray_bin = Path(sys.executable).with_name("ray")
    head = cluster.address
    node = subprocess.Popen(
        ["unshare", "--mount", "--propagation", "private", "sh", "-c",
         f"mount -t tmpfs none {shared} && exec {ray_bin} start --address={head} --num-cpus=1 "
         f"--object-store-memory={80 * 2**20} --block"],
        start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    backend = RayExecutor(head)
    try:
        ray_module = backend.connect()
        deadline = time.monotonic() + 120
        while sum(n["Alive"] for n in ray_module.nodes()) < 2:
            assert time.monotonic() < deadline and node.poll() is None, "the second node did not join"
            time.sleep(0.5)
        with pytest.raises(ConfigError, match=r"not visible on Ray node\(s\) .*mounts") as info:
            generate(load_config(TINY), shared / "data", "train", 1, progress=False, executor=backend)
        assert "\n" not in str(info.value)
        assert list(shared.iterdir()) == []
    finally:
        backend.close()
        os.killpg(node.pid, 15)
        node.wait(timeout=60)
