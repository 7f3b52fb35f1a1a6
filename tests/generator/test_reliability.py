"""A rerun mends what a crash or damage left (real Cycles renders at tiny size), `dotsim verify`
and `--repair`, and a full disk (a real, tiny tmpfs when this runs as root; an ENOSPC raised at
fsync otherwise) reported in one line that names the file, leaving nothing half-written."""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from commands.cli import main as dotsim_main
from dotsim import dataset, file_io
from dotsim.dataset.layout import record_layout
from dotsim.dataset.seal import seal_shard
from generator.config import load_config
from generator.driver import generate
from generator.render_worker import LOG_DIR
from generator.resources import TEXTURE_DIR
from tests.output_folders import leftovers

REPO = Path(__file__).resolve().parents[2]
TINY = REPO / "dotsim" / "configs" / "tiny.toml"
SCENES = 6  # three shards of two scenes (dotsim/configs/tiny.toml)


def frame_sums(root: Path) -> dict[str, str]:
    """sha256 of every frame file, by path relative to the dataset (computed with hashlib)."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.glob("shard_*/scene_*/frame_*.exr"))}


@pytest.fixture(scope="module")
def sealed(tmp_path_factory):
    """SCENES tiny scenes rendered and sealed once; tests work on copies."""
    out = tmp_path_factory.mktemp("reliability") / "base"
    summary = generate(load_config(TINY), out, "train", SCENES, seed=3, progress=False)
    assert summary.done == SCENES and not summary.failed
    return out


def rerun(out: Path, scenes: int = SCENES):
    return generate(load_config(TINY), out, "train", scenes, seed=3, progress=False)


def test_rerun_reseals_after_a_kill_between_the_last_scene_and_the_seal(sealed, tmp_path):
    """The state a kill leaves while extending a sealed dataset 3 -> 6 scenes: every scene written,
    index.json still the old seal, and one shard.json already rewritten (killed mid-seal)."""
    out = tmp_path / "extended"
    shutil.copytree(sealed, out)
    moved = [dataset.scene_dir(out, index, 2) for index in (3, 4, 5)]
    for scene in moved:
        scene.rename(tmp_path / scene.name)
    dataset.seal_dataset(out)  # the seal of the first 3 scenes
    for scene in moved:
        (tmp_path / scene.name).rename(scene)
    assert dataset.open_dataset(out).index["scene_count"] == 3
    seal_shard(out / "shard_00001", 1, 2)  # shard.json written, index.json not: the kill
    with pytest.raises(dataset.FormatError, match=r"shard_00001/shard\.json: sha256 differs"):
        dataset.open_dataset(out)
    summary = rerun(out)
    assert (summary.done, summary.skipped, summary.failed) == (0, SCENES, [])
    data = dataset.open_dataset(out, verify=True)
    assert [s.scene_index for s in data.scenes] == list(range(SCENES))
    assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()
    assert not dataset.verify_dataset(out).problems


def test_rerun_redoes_a_damaged_complete_scene(sealed, tmp_path):
    out = tmp_path / "damaged"
    shutil.copytree(sealed, out)
    (out / "shard_00001" / "scene_0000003" / "frame_2.exr").unlink()  # e.g. a bad copy
    summary = rerun(out)
    assert (summary.done, summary.skipped, summary.failed, summary.redone) == (1, SCENES - 1, [], [3])
    assert "1 damaged scene(s) found and redone: [3]" in summary.line()
    assert frame_sums(out) == frame_sums(sealed)  # byte-identical to the first rendering
    assert not dataset.verify_dataset(out).problems
    assert not leftovers(out)


def test_verify_lists_damage_by_file_and_repair_makes_the_rerun_redo_exactly_it(sealed, tmp_path, capsys):
    out = tmp_path / "copied"
    shutil.copytree(sealed, out)
    shard0, shard2 = out / "shard_00000", out / "shard_00002"
    (shard0 / "scene_0000001" / "frame_0.exr").unlink()
    corrupt = shard2 / "scene_0000004" / "frame_3.exr"
    data = bytearray(corrupt.read_bytes())
    data[len(data) // 2] ^= 0xFF
    corrupt.write_bytes(bytes(data))
    (out / "shard_00001" / "scene_0000002" / "scene.json").write_text("{ not json")
    stale = shard2 / ".tmp-scene_0000005-999999999"  # a crashed writer's leftover (no such pid)
    stale.mkdir()
    assert dotsim_main(["verify", str(out)]) == 1
    captured = capsys.readouterr()
    lines = captured.out.splitlines()
    assert f"{shard0 / 'scene_0000001' / 'frame_0.exr'}: missing (listed in scene.json)" in lines
    assert f"{corrupt}: sha256 differs from the one scene.json recorded at write time (file changed " \
           f"or corrupt)" in lines
    assert any(line.startswith(f"{out / 'shard_00001' / 'scene_0000002' / 'scene.json'}: not valid JSON")
               for line in lines)
    assert f"{stale}: unfinished write left by a crashed writer" in lines
    assert "4 problem(s) (3 damaged scene(s): 1, 2, 4)" in captured.err
    assert dotsim_main(["verify", str(out), "--repair"]) == 0
    captured = capsys.readouterr()
    assert "repair: removed 3 damaged scene(s) and 1 leftover(s)" in captured.out
    assert "render scenes 1, 2, 4 again" in captured.out
    assert [s.scene_index for s in dataset.open_dataset(out).scenes] == [0, 3, 5]
    summary = rerun(out)
    assert (summary.done, summary.skipped, summary.failed) == (3, SCENES - 3, [])
    assert frame_sums(out) == frame_sums(sealed)
    assert dotsim_main(["verify", str(out)]) == 0
    assert "no problems" in capsys.readouterr().out


def test_verify_names_a_stale_seal_and_seal_mends_it(sealed, tmp_path, capsys):
    out = tmp_path / "stale"
    shutil.copytree(sealed, out)
    scene = out / "shard_00002" / "scene_0000005"
    scene.rename(tmp_path / "aside")
    assert dotsim_main(["verify", str(out)]) == 1
    assert f"{scene}: missing (listed in {scene.parent / 'shard.json'}); sealing again drops it" \
        in capsys.readouterr().out
    assert dotsim_main(["seal", str(out)]) == 0
    assert "sealed 5 scenes (20 frames) in 3 shard(s): 1 shard.json written, 0 scenes hashed" \
        in capsys.readouterr().out
    (tmp_path / "aside").rename(scene)
    assert dotsim_main(["verify", str(out)]) == 1
    assert f"{scene}: complete but not sealed" in capsys.readouterr().out
    assert dotsim_main(["seal", str(out)]) == 0
    assert "1 scenes hashed" in capsys.readouterr().out
    assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()


def test_cluster_tasks_leave_the_seal_to_one_final_seal(sealed, tmp_path, capsys):
    out = tmp_path / "cluster"
    shutil.copytree(sealed, out, ignore=shutil.ignore_patterns("index.json", "shard.json"))
    summary = generate(load_config(TINY), out, "train", 2, start=4, seed=3, progress=False, seal=False)
    # The task's range is shard 2, wholly: it sealed that shard, and only that.
    assert summary.skipped == 2 and not (out / "index.json").exists()
    assert [p.parent.name for p in sorted(out.glob("shard_*/shard.json"))] == ["shard_00002"]
    assert dotsim_main(["seal", str(out)]) == 0
    assert f"sealed {SCENES} scenes ({4 * SCENES} frames) in 3 shard(s): 2 shard.json written, " \
           f"{SCENES - 2} scenes hashed" in capsys.readouterr().out
    assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()


# ----------------------------------------------------------------------------- processes and writers


def running(pid: int) -> bool:
    """True while process `pid` exists and is not a zombie (a zombie holds no files and runs nothing)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return False
    return stat[stat.rindex(")") + 2] != "Z"


def descendants(pid: int) -> set[int]:
    """Every process below `pid` (children, their children, ...), from /proc."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        ppid = int(text[text.rindex(")") + 2:].split()[1])
        children.setdefault(ppid, []).append(int(stat.parent.name))
    found, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            if child not in found:
                found.add(child)
                todo.append(child)
    return found


def start_generate(out: Path, workers: int = 2) -> subprocess.Popen:
    """`dotsim generate` of SCENES tiny scenes in a process of its own, from this checkout, with its
    stdout a pipe (as `dotsim generate ... | tee log` has it)."""
    command = [sys.executable, "-m", "commands.cli", "generate", "--config", str(TINY), "--out", str(out),
               "--split", "train", "--scenes", str(SCENES), "--seed", "3", "--workers", str(workers),
               "--no-progress"]
    return subprocess.Popen(command, cwd=REPO, env={**os.environ, "PYTHONPATH": str(REPO)},
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def wait_rendering(proc: subprocess.Popen, out: Path, workers: int) -> set[int]:
    """Wait until the run has its workers and its first scene on disk (half or wholly written: a scene
    is encoded in memory, so its temp folder lives only milliseconds); the run's processes then, with
    the other scenes still rendering."""
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if list(out.glob("shard_*/*scene_*")) and len(descendants(proc.pid)) >= workers:
            return descendants(proc.pid)
        time.sleep(0.02)
    pytest.fail(f"the run never had {workers} workers rendering (exit {proc.poll()})")


def output_closed_within(proc: subprocess.Popen, seconds: float) -> str | None:
    """The run's output once every holder of its stdout closed it, or None after `seconds`
    (a `| tee log` would hang)."""
    text: list[str] = []
    reader = threading.Thread(target=lambda: text.append(proc.stdout.read()), daemon=True)
    reader.start()
    reader.join(seconds)
    return None if reader.is_alive() else text[0]


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGTERM, signal.SIGHUP],
                         ids=["kill-9", "SIGTERM", "SIGHUP"])
def test_a_stopped_run_leaves_no_process_behind(sealed, tmp_path, signum):
    """kill -9 of `dotsim generate --workers 2` mid-scene: within 10 s no process of the run is left
    (workers, resource tracker), its stdout is closed, and the rerun equals a clean run byte for
    byte. SIGTERM and SIGHUP tear the pool down and exit 128 + the signal."""
    out = tmp_path / "stopped"
    proc = start_generate(out)
    family = wait_rendering(proc, out, workers=2)
    os.kill(proc.pid, signum)
    text = output_closed_within(proc, 10.0)
    assert text is not None, "the run's stdout stayed open 10 s after it was stopped"
    deadline = time.monotonic() + 10.0
    while [pid for pid in family if running(pid)] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in family if running(pid)], f"left running: {[p for p in family if running(p)]}"
    assert proc.wait(timeout=10) == (-signal.SIGKILL if signum == signal.SIGKILL else 128 + signum)
    if signum != signal.SIGKILL:
        assert f"stopped by {signal.Signals(signum).name}; workers stopped" in text, text
        return
    summary = rerun(out)
    assert summary.done + summary.skipped == SCENES and not summary.failed
    assert frame_sums(out) == frame_sums(sealed)
    assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()
    assert not leftovers(out)


def run_of(command: list[str], ready, signum: int, seconds: float = 10.0) -> tuple[int, str]:
    """Start `command` (a dotsim command line) from this checkout, wait until ready(proc) is true,
    send `signum` to its main process and check by pid that none of its processes is left after
    `seconds`; (exit status, output)."""
    proc = subprocess.Popen([sys.executable, "-m", "commands.cli", *command], cwd=REPO, text=True,
                            env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 300
    while not ready(proc):
        assert proc.poll() is None and time.monotonic() < deadline, f"never ready (exit {proc.poll()})"
        time.sleep(0.02)
    family = descendants(proc.pid)
    os.kill(proc.pid, signum)
    text = output_closed_within(proc, seconds)
    assert text is not None, f"the output stayed open {seconds} s after the stop"
    deadline = time.monotonic() + seconds
    while [pid for pid in family if running(pid)] and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [pid for pid in family if running(pid)], f"left running: {[p for p in family if running(p)]}"
    return proc.wait(timeout=seconds), text


def test_a_killed_ray_local_driver_leaves_no_ray_process(tmp_path):
    """kill -9 of `dotsim generate --ray local` mid-run, once its first scene is under way or done:
    its cluster (raylet, agents, the workers running tasks) is gone within 10 s."""
    pytest.importorskip("ray")
    out = tmp_path / "ray"
    # enough scenes that the run is still going when one is seen (a tiny scene's temporary folder
    # can come and go between two looks on idle cores)
    command = ["generate", "--config", str(TINY), "--out", str(out), "--split", "train", "--scenes",
               str(8 * SCENES), "--seed", "3", "--workers", "2", "--no-progress", "--ray", "local"]
    status, _ = run_of(command, lambda proc: bool(list(out.glob("shard_*/*scene_*"))), signal.SIGKILL)
    assert status == -signal.SIGKILL


@pytest.mark.parametrize("signum", [signal.SIGKILL, signal.SIGTERM], ids=["kill-9", "SIGTERM"])
def test_a_stopped_train_nproc_leaves_no_rank_behind(tmp_path, signum):
    from dotsim.oracle_dataset import make_dataset

    data, run = make_dataset(tmp_path / "data", scenes=2), tmp_path / "run"
    command = ["train", "--config", str(REPO / "dotsim" / "configs" / "train_tiny.toml"), "--data", str(data),
               "--out", str(run), "--nproc", "2"]
    status, text = run_of(command, lambda proc: (run / "tb").is_dir() and len(descendants(proc.pid)) >= 2,
                          signum)
    assert status == (-signal.SIGKILL if signum == signal.SIGKILL else 128 + signum), text
    if signum == signal.SIGTERM:
        assert "dotsim train: stopped by SIGTERM\n" in text, text


def test_capture_record_stopped_by_sigterm_keeps_its_frames(tmp_path):
    import cv2

    from dotsim.rig.files import rig_file_json
    from dotsim.rig.presets import get_preset

    rig = get_preset("structure_core").scaled(0.1)
    video = tmp_path / "ir.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 30,
                             (rig.camera.width, rig.camera.height), isColor=False)
    rng = np.random.default_rng(0)
    for _ in range(40):
        writer.write(rng.integers(0, 256, (rig.camera.height, rig.camera.width), dtype=np.uint8))
    writer.release()
    (tmp_path / "rig.json").write_bytes(rig_file_json(rig))
    out = tmp_path / "rec"
    command = ["capture", "record", "--device", f"opencv:{video}", "--rig", str(tmp_path / "rig.json"),
               "--out", str(out), "--scenes", "10", "--frames", "2", "--pause", "0.2", "--no-progress",
               "--no-preview"]
    status, text = run_of(command, lambda proc: (out / "shard_00000" / "scene_0000000").is_dir(),
                          signal.SIGTERM)
    assert status == 128 + signal.SIGTERM, text
    assert "stopped: stopped by SIGTERM; kept every complete frame" in text, text
    assert len(dataset.open_dataset(out, verify=True).scenes) >= 1


HOLD_LOCK = """
import sys, time
from dotsim.dataset.lock import writer_lock
with writer_lock(sys.argv[1], "dotsim generate"):
    print("held", flush=True)
    time.sleep(600)
"""


def test_a_second_writer_is_refused_naming_the_holder_and_range_tasks_go_on(sealed, tmp_path, capsys):
    out = tmp_path / "locked"
    shutil.copytree(sealed, out)
    holder = subprocess.Popen([sys.executable, "-c", HOLD_LOCK, str(out)], cwd=REPO, text=True,
                              env={**os.environ, "PYTHONPATH": str(REPO)}, stdout=subprocess.PIPE)
    try:
        assert holder.stdout.readline() == "held\n"
        assert dotsim_main(["generate", "--config", str(TINY), "--out", str(out), "--split", "train",
                            "--scenes", str(SCENES), "--seed", "3", "--no-progress"]) == 1
        assert capsys.readouterr().err == (f"dotsim generate: error: {out}: another writer holds this "
                                           f"dataset "
                                           f"(pid {holder.pid}: dotsim generate); wait for it to end, or "
                                           f"write elsewhere\n")
        assert dotsim_main(["verify", str(out), "--repair"]) == 2
        assert f"(pid {holder.pid}: dotsim generate)" in capsys.readouterr().err
        # a cluster task writing its own range (--no-seal) takes no lock
        task = generate(load_config(TINY), out, "train", 2, start=4, seed=3, progress=False, seal=False)
        assert (task.skipped, task.failed) == (2, [])
    finally:
        holder.kill()
        holder.wait()
    # the kernel dropped the killed holder's lock: the next writer goes ahead
    assert rerun(out).skipped == SCENES


# ----------------------------------------------------------------------------- only checksums are trusted


def test_repair_removes_a_scene_edited_after_sealing_and_never_reseals_it(sealed, tmp_path, capsys):
    """A hand edit of a sealed scene.json (its frames untouched, so scene.json still lists their
    right checksums) is damage: seal refuses it, repair removes the scene, the rerun renders it."""
    out = tmp_path / "edited"
    shutil.copytree(sealed, out)
    scene_json = out / "shard_00001" / "scene_0000003" / "scene.json"
    text = scene_json.read_text()
    fx = text.index('"fx": ') + len('"fx": ')
    scene_json.write_text(text[:fx] + "1" + text[fx:])  # e.g. 111.544 -> 1111.544
    assert dotsim_main(["verify", str(out)]) == 1
    assert f"{scene_json}: sha256 differs from its entry in {scene_json.parents[1] / 'shard.json'} " \
           "(changed after it was sealed); repair removes the scene" in capsys.readouterr().out
    assert dotsim_main(["seal", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{scene_json}: differs from its entry" in err, err
    assert dotsim_main(["verify", str(out), "--repair"]) == 0
    assert "repair: removed 1 damaged scene(s)" in capsys.readouterr().out
    assert not scene_json.parent.exists()
    assert dotsim_main(["verify", str(out)]) == 0
    summary = rerun(out)
    assert (summary.done, summary.skipped) == (1, SCENES - 1)
    assert scene_json.read_bytes() == (sealed / scene_json.relative_to(out)).read_bytes()
    assert frame_sums(out) == frame_sums(sealed)
    assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()


def test_a_wrong_checksum_inside_shard_json_is_mended_by_repair_and_by_seal(sealed, tmp_path, capsys):
    for mend in (["verify", "--repair"], ["seal"]):
        out = tmp_path / mend[-1].strip("-")
        shutil.copytree(sealed, out)
        shard_json = out / "shard_00001" / "shard.json"
        shard = json.loads(shard_json.read_text())
        shard["scenes"][0]["files"]["frame_1.exr"] = "0" * 64
        shard_json.write_text(json.dumps(shard))
        assert dotsim_main(["verify", str(out)]) == 1
        lines = capsys.readouterr().out.splitlines()
        assert f"{shard_json}: its entry for scene_0000002 does not list the checksums scene.json " \
               "records; repair derives it again from the frames" in lines
        assert dotsim_main([mend[0], str(out), *mend[1:]]) == 0
        capsys.readouterr()
        assert dotsim_main(["verify", str(out)]) == 0, capsys.readouterr().out
        assert shard_json.read_bytes() == (sealed / "shard_00001" / "shard.json").read_bytes()
        assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()
        assert sorted(p.parent.name for p in out.glob("shard_*/scene_*/scene.json")) == \
            sorted(p.parent.name for p in sealed.glob("shard_*/scene_*/scene.json"))


@pytest.mark.parametrize("key, value", [
    ("scene_count", 7), ("frame_count", 23), ("split_counts", {"train": 5}), ("scenes_per_shard", 3),
    ("dotsim_version", "9.9.9"), ("shards.1.scene_count", 1)])
def test_verify_checks_index_json_summary_fields_and_repair_rewrites_them(sealed, tmp_path, capsys, key,
                                                                           value):
    out = tmp_path / "summary"
    shutil.copytree(sealed, out)
    index = json.loads((out / "index.json").read_text())
    *path, last = key.split(".")
    where = index
    for part in path:
        where = where[int(part)] if isinstance(where, list) else where[part]
    where[last] = value
    (out / "index.json").write_text(json.dumps(index))
    assert dotsim_main(["verify", str(out)]) == 1
    top = key.split(".")[0]
    lines = capsys.readouterr().out.splitlines()
    assert any(line.startswith(f"{out / 'index.json'}: {top} is ") for line in lines), lines
    assert dotsim_main(["verify", str(out), "--repair"]) == 0
    assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()


# ----------------------------------------------------------------------------- inputs checked before use

@pytest.fixture(scope="module")
def asset_cache(tmp_path_factory):
    """A small test-split asset cache (tests/generator/test_generate.py's, with 3 meshes) and its manifest."""
    from assets_manifest.cache import build_asset_cache
    from assets_manifest.manifest import load_manifest
    from tests.generator.test_generate import CACHE_MANIFEST

    root = tmp_path_factory.mktemp("assets")
    assert CACHE_MANIFEST.count("seeds = [0, 1]") == 2  # meshes, then textures
    (root / "test.toml").write_text(CACHE_MANIFEST.replace("seeds = [0, 1]", "seeds = [0, 3]", 1))
    build_asset_cache(load_manifest(root / "test.toml"), root / "cache", "test", progress=False,
                      log=lambda *args: None)
    return root


def copied_cache(asset_cache: Path, tmp_path: Path) -> tuple[Path, Path]:
    """A copy of the cache and a tiny config rendering from it: (cache, config)."""
    shutil.copytree(asset_cache / "cache", tmp_path / "cache")
    config = tmp_path / "cached.toml"
    config.write_text(TINY.read_text() + '\n[assets]\nsource = "cache"\ncache_dir = "cache"\n')
    return tmp_path / "cache", config


def garble(path: Path) -> None:
    """Zero 64 bytes in the middle of a file, as a bad disk or copy would."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2:len(data) // 2 + 64] = bytes(64)
    path.write_bytes(bytes(data))


def generate_line(config: Path, out: Path, scenes: int, capsys, split: str = "train") -> tuple[int, str]:
    status = dotsim_main(["generate", "--config", str(config), "--out", str(out), "--split", split,
                          "--scenes", str(scenes), "--seed", "3", "--no-progress"])
    return status, capsys.readouterr().err


def test_a_damaged_builtin_texture_stops_the_run_before_it_renders(sealed, tmp_path, capsys):
    out = tmp_path / "textures"
    shutil.copytree(sealed, out)
    texture = sorted((out / TEXTURE_DIR).glob("*.png"))[1]
    garble(texture)
    for record in (True, False):  # textures/checksums.json, or a dataset from before it (no record)
        if not record:
            (out / TEXTURE_DIR / "checksums.json").unlink()
        status, err = generate_line(TINY, out, SCENES + 1, capsys)
        assert status == 2 and err.count("\n") == 1, err
        assert err.startswith(f"dotsim generate: error: {texture}: sha256 "), err
        assert "differs from the " in err, err
        assert not (out / "shard_00003").exists()


def test_a_damaged_cache_file_stops_the_run_and_one_changed_mid_run_fails_its_scenes(asset_cache, tmp_path,
                                                                                      capsys):
    from generator.engines.steps import prepare_run
    from generator.render_worker import _sample, render_scenes
    from generator.run_request import RunRequest

    cache, config = copied_cache(asset_cache, tmp_path)
    texture = sorted((cache / "test" / "textures").glob("*.png"))[0]
    original = texture.read_bytes()
    garble(texture)
    status, err = generate_line(config, tmp_path / "out", 1, capsys, "test")
    assert status == 2 and err.count("\n") == 1, err
    assert f"asset file {texture} does not match its sha256 in the index" in err, err
    # damaged after the run checked it (prepare_run) and before a render reads it: the scene fails
    texture.write_bytes(original)
    job = prepare_run(RunRequest(load_config(config), tmp_path / "out", "test", 1, seed=3))
    mesh = Path(next(p for p in map(Path, dataset_inputs(_sample(job, 0))) if p.suffix == ".npz"))
    garble(mesh)
    [result] = render_scenes(job, [0])
    assert not result.ok and f"{mesh}: sha256 " in result.error, result.error
    assert "recorded when it was made" in result.error
    assert not dataset.is_scene_complete(tmp_path / "out", 0, 2)


def dataset_inputs(spec) -> list[str]:
    from generator.render_worker import spec_inputs

    return spec_inputs(spec)


def test_assets_check_reports_every_garbled_mesh(asset_cache, tmp_path, capsys):
    cache, _ = copied_cache(asset_cache, tmp_path)
    meshes = sorted((cache / "test" / "meshes").glob("*.npz"))
    for mesh in meshes:
        garble(mesh)
    assert dotsim_main(["assets", "check", "--cache", str(cache), "--test-manifest",
                        str(asset_cache / "test.toml")]) == 1
    out = capsys.readouterr().out
    for mesh in meshes:
        assert f"problem: asset file {mesh.resolve()} does not match its sha256 in the index" in out, out
    assert "problem(s)" in out


def test_an_asset_cache_entry_missing_keys_is_one_line(asset_cache, tmp_path, capsys):
    cache, config = copied_cache(asset_cache, tmp_path)
    index_path = cache / "test" / "index.json"
    index = json.loads(index_path.read_text())
    del index["meshes"][1]["path"]
    index_path.write_text(json.dumps(index))
    status, err = generate_line(config, tmp_path / "out", 1, capsys, "test")
    assert status == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert f"asset cache index {index_path.resolve()}: meshes entry 1 ({index['meshes'][1]['id']}) lacks " \
           "key(s) ['path']" in err, err
    assert not (tmp_path / "out").exists()
    assert dotsim_main(["assets", "check", "--cache", str(cache), "--test-manifest",
                        str(asset_cache / "test.toml")]) == 1
    assert "lacks key(s) ['path']" in capsys.readouterr().out


# ----------------------------------------------------------------------------- a full disk


@contextlib.contextmanager
def tmpfs(mount: Path, size: str):
    """A real tmpfs of `size` mounted at `mount` (root only; else the test is skipped)."""
    mount.mkdir()
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root; the fsync-level ENOSPC test still runs")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=True)


@pytest.fixture
def small_disk(tmp_path):
    """A real 8 MB tmpfs mounted at tmp_path / "disk" (root only), unmounted afterwards."""
    with tmpfs(tmp_path / "disk", "8m") as mount:
        yield mount


def fill(disk: Path, leave: int = 0) -> None:
    """Fill the filesystem until a write fails with ENOSPC (a real full disk), then free `leave`
    bytes again."""
    # Unbuffered: a buffered file keeps the bytes its last flush could not write and raises ENOSPC
    # again when the with-block closes it (so the test failed or passed with the free space's size).
    with open(disk / "filler", "wb", buffering=0) as stream:
        try:
            while True:
                stream.write(b"\0" * 65536)
        except OSError as error:
            assert error.errno == errno.ENOSPC
    with pytest.raises(OSError):
        (disk / "probe").write_bytes(b"x")
    (disk / "probe").unlink(missing_ok=True)
    if leave:
        os.truncate(disk / "filler", (disk / "filler").stat().st_size - leave)


def assert_one_line_naming(err: str, path: Path) -> None:
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert f"{path}: no space left on device: writing it needs" in err and "free on" in err, err


def test_full_disk_while_writing_the_builtin_textures(sealed, small_disk, capsys):
    out = small_disk / "out"
    out.mkdir()
    for name in ("pattern.png", "generate.json"):
        shutil.copy(sealed / name, out / name)
    fill(small_disk)
    assert dotsim_main(["generate", "--config", str(TINY), "--out", str(out), "--split", "train",
                        "--scenes", "1", "--seed", "3", "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert_one_line_naming(err, out / TEXTURE_DIR / sorted((sealed / TEXTURE_DIR).glob("*.png"))[0].name)
    assert not leftovers(small_disk)


def test_full_disk_while_writing_a_failure_log(sealed, small_disk, capsys):
    out = small_disk / "out"
    shutil.copytree(sealed, out, ignore=shutil.ignore_patterns("shard_*", "index.json", "dataset.json"))
    fill(small_disk)
    # /bin/false renders nothing, so the scene fails and its log is written: the disk is full.
    assert dotsim_main(["generate", "--config", str(TINY), "--out", str(out), "--split", "train",
                        "--scenes", "1", "--seed", "3", "--no-progress", "--blender", "/bin/false"]) == 1
    assert_one_line_naming(capsys.readouterr().err, out / LOG_DIR / "scene_0000000.log")
    assert not leftovers(small_disk)


def test_full_disk_while_writing_a_scene(sealed, small_disk, capsys):
    out = small_disk / "out"
    shutil.copytree(sealed, out, ignore=shutil.ignore_patterns("shard_*", "index.json"))
    fill(small_disk)
    assert dotsim_main(["generate", "--config", str(TINY), "--out", str(out), "--split", "train",
                        "--scenes", "1", "--seed", "3", "--no-progress"]) == 1
    assert_one_line_naming(capsys.readouterr().err, out / "shard_00000" / "scene_0000000")
    assert not leftovers(small_disk) and not list(out.glob("shard_*/scene_*"))


def test_full_disk_while_sealing(sealed, small_disk, capsys):
    out = small_disk / "out"
    shutil.copytree(sealed, out, ignore=shutil.ignore_patterns("index.json"))
    fill(small_disk)
    assert dotsim_main(["seal", str(out)]) == 1
    assert_one_line_naming(capsys.readouterr().err, out / "index.json")
    assert not leftovers(small_disk)
    (small_disk / "filler").unlink()
    assert dotsim_main(["seal", str(out)]) == 0
    assert (out / "index.json").read_bytes() == (sealed / "index.json").read_bytes()


# TensorBoard's writer thread meets the full disk first: its traceback must not reach the user either.
@pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")
def test_train_on_a_full_disk_is_one_line_and_keeps_the_last_good_checkpoint(tmp_path, capsys):
    """TensorBoard's event file, then the checkpoint, meet a full disk: each a one-line message naming
    the file, exit 1, and checkpoint.pt still the last good one (it is 15.5 MB: a 40 MB tmpfs)."""
    from dotsim.oracle_dataset import make_dataset
    from trainer.checkpoint import load_checkpoint

    data = make_dataset(tmp_path / "data", scenes=2)
    tiny = (REPO / "dotsim" / "configs" / "train_tiny.toml").read_text()
    for steps in (2, 4):
        (tmp_path / f"train_{steps}.toml").write_text(tiny.replace("max_steps = 200", f"max_steps = {steps}"))

    def train(steps: int, *resume: str) -> int:
        return dotsim_main(["train", "--config", str(tmp_path / f"train_{steps}.toml"), "--data", str(data),
                            "--out", str(run), *resume])

    with tmpfs(tmp_path / "disk", "40m") as disk:
        run = disk / "run"
        assert train(2) == 0
        good = (run / "checkpoint.pt").read_bytes()
        capsys.readouterr()
        for leave, named in ((0, run / "tb"), (1 << 20, run / "checkpoint.pt")):
            fill(disk, leave)  # nothing left; then room for TensorBoard's events, not for a checkpoint
            assert train(4, "--resume") == 1
            full = capsys.readouterr().err
            err = full.splitlines()[-1]  # after the progress bar
            assert "Traceback" not in full, full
            assert err.startswith(f"dotsim train: error: {named}") and "no space left on device" in err, err
            assert (run / "checkpoint.pt").read_bytes() == good
            assert not list(disk.rglob(".tmp-*"))
            (disk / "filler").unlink()
        assert load_checkpoint(run / "checkpoint.pt")[0]["step"] == 2
        assert train(4, "--resume") == 0


def test_enospc_at_fsync_names_the_file_and_leaves_nothing(tmp_path, monkeypatch):
    """Where no tmpfs can be mounted: the OS reporting ENOSPC when the data reaches the disk."""
    def no_space(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    record_layout(tmp_path, 2)  # dataset.json, written before the disk "fills"
    monkeypatch.setattr(file_io.os, "fsync", no_space)
    target = tmp_path / "index.json"
    with pytest.raises(file_io.DiskFullError) as caught:
        file_io.atomic_write_bytes(target, b"x" * 3000)
    assert str(caught.value).startswith(f"{target}: no space left on device: writing it needs 2.9 kB, ")
    assert caught.value.errno == errno.ENOSPC
    assert [p.name for p in tmp_path.iterdir()] == ["dataset.json"]
    with pytest.raises(file_io.DiskFullError, match=r"scene_0000000: no space left on device"):
        dataset.write_scene(tmp_path, 0, *_tiny_scene())
    assert not leftovers(tmp_path) and not list(tmp_path.glob("shard_*/scene_*"))


def _tiny_scene():
    from dotsim.rig.presets import get_preset

    rig = get_preset("structure_core").scaled(0.025)
    h, w = rig.camera.height, rig.camera.width
    frame = {"ir": np.zeros((h, w)), "depth": np.ones((h, w), np.float32)}
    meta = {"split": "train", "rig": rig.to_dict(), "pattern": {}, "poses": [None]}
    return meta, [frame], 2, ("ir", "depth")
