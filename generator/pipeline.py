"""The generator run: config -> pattern and textures -> W render workers -> post-render -> shards.

`generate()` validates everything before it writes anything (config values, output directory,
Blender executable, an existing dataset's config), then:
  1. gets the dataset folder ready (`prepare_run`): takes its writer lock (dotsim.dataset.lock; a
     second local writer is refused naming the holder), removes partial scenes left by a crashed
     run, writes the projector pattern once (DATASET/pattern.png), the run record and the built-in
     textures it needs (generator/resources.py), and notes the sha256 of every input file a render
     reads, which each worker checks before it renders a scene;
  2. skips complete scenes (resume), removes damaged ones (a frame deleted after the fact) and
     renders them with the others in W spawned worker processes
     (generator/render_scenes.py: sample, render, post-render, write each scene atomically; a
     failing scene is logged and the run goes on);
  3. seals the dataset (dotsim.dataset.seal_dataset: incremental, so every run seals, and a run
     killed before its seal leaves nothing a rerun does not mend) and returns a RunSummary.
Past one machine: with a backend (generator/ray_cluster.py) step 2 runs as Ray tasks, each
`render_scenes(job, indices)` on a share; a Slurm array task (generator/slurm.py) is this same run
on its range with seal=False, and a final job seals what the tasks wrote (`seal_run`).
Scene k is sampled from (config, k, base seed) alone, so the output does not depend on W.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from tqdm import tqdm

import dotsim
from dotsim import dataset
from dotsim.dataset.lock import writer_lock
from dotsim.dataset.seal import seal_shard, vouched_shards
from dotsim.file_io import json_bytes, sha256_file
from dotsim.pattern_store import pattern_entry, store_pattern
from generator.config import Config, ConfigError, check_output_dir
from generator.render_scenes import LOG_DIR, RUN_IN_BLENDER, RenderJob, SceneResult, render_pool
from generator.resources import config_pattern, input_checksums, split_assets
from generator.scene_spec import SPLITS

RUN_FILE = "generate.json"
# Scenes per `blender` call: large enough to amortise Blender's start-up (seconds), small enough
# that the progress bar moves and a crash loses little.
BLENDER_BATCH = 8


@dataclass
class RunSummary:
    """What a run did; `line()` is the summary printed at the end."""
    out: Path
    done: int = 0
    skipped: int = 0
    frames: int = 0
    seconds: float = 0.0
    worker_seconds: float = 0.0
    failed: list[int] = field(default_factory=list)
    redone: list[int] = field(default_factory=list)  # damaged scenes found, removed and rendered again
    unsealed: str = ""  # why the run could not seal (other writers kept changing the dataset)

    def line(self) -> str:
        per_scene = (f"{self.seconds / self.done:.2f} s/scene; {self.worker_seconds / self.done:.2f} s of "
                     "one worker's time each" if self.done else "no scene rendered")
        scenes = "scene" if self.done == 1 else "scenes"
        text = (f"{self.done} {scenes} rendered ({self.frames} frames), {self.skipped} already complete, "
                f"{len(self.failed)} failed, in {self.seconds:.1f} s ({per_scene}) -> {self.out}")
        if self.unsealed:
            text += f"; not sealed: {self.unsealed}"
        if self.redone:
            text += f"; {len(self.redone)} damaged scene(s) found and redone: {self.redone[:10]}"
        if self.failed:
            text += f"; failed scenes {self.failed[:10]}{' ...' if len(self.failed) > 10 else ''}, " \
                    f"tracebacks in {self.out / LOG_DIR}"
        return text


def _run_record(config: Config, split: str, seed: int) -> dict:
    """What must stay the same for scenes to belong to one dataset (the config's file name may vary)."""
    settings = config.to_dict()
    settings.pop("source")
    return {"split": split, "base_seed": seed, "config": settings}


def _check_existing_run(out: Path, record: dict) -> None:
    path = out / RUN_FILE
    if not path.exists():
        return
    try:
        existing = json.loads(path.read_text())
    except ValueError as exc:
        raise ConfigError(f"{path}: unreadable ({exc}); remove it or use a new --out") from None
    if existing != record:
        changed = [key for key in ("split", "base_seed") if existing.get(key) != record[key]]
        sections = sorted(name for name, value in record["config"].items()
                          if existing.get("config", {}).get(name) != value)
        what = ", ".join(changed + [f"[{name}]" for name in sections]) or "settings"
        raise ConfigError(f"{out}: already holds scenes generated with different {what}; resume with "
                          f"the same config, --split and --seed, or use a new --out")


def versions(blender: str | None) -> dict:
    """Software versions recorded in every scene (Blender: the bpy module or the executable)."""
    if blender:
        first = subprocess.run([blender, "--version"], capture_output=True, text=True,
                               timeout=120).stdout.splitlines()
        blender_version = first[0].strip() if first else "unknown"
    else:
        blender_version = f"bpy {importlib.metadata.version('bpy')}"
    return {"dotsim": dotsim.__version__, "blender": blender_version, "numpy": np.__version__,
            "python": platform.python_version()}


# ----------------------------------------------------------------------------- the run


def check_blender(blender: str | None) -> str | None:
    """Absolute path of the Blender executable, or ConfigError naming it."""
    if blender is None:
        return None
    found = shutil.which(blender)
    if found is None:
        raise ConfigError(f"--blender {blender}: not an executable file; allowed: the path of a Blender "
                          "5.0 executable, or leave --blender out to use the bpy module")
    if not RUN_IN_BLENDER.is_file():
        raise ConfigError(f"--blender: the entry script {RUN_IN_BLENDER} is missing from this install")
    return str(Path(found).resolve())


def prepare_run(config: Config, out: str | os.PathLike, split: str, seed: int = 0,
                blender: str | None = None, backend=None, own: range | None = None,
                hold: contextlib.ExitStack | None = None) -> RenderJob:
    """Check a run and get its dataset folder `out` ready; the RenderJob that renders its scenes.

    Raises ConfigError before anything is written when an argument, the output directory, the
    Blender executable, the pattern, the asset cache or an existing dataset in `out` does not fit,
    or when `backend.start(out, config)` does (a cluster that cannot be reached or whose nodes do
    not see `out`). Then removes scenes a crashed run left half-written, stores the pattern and the
    run record (DATASET/generate.json) and writes the built-in textures of `split`.

    own: the scenes this run writes while other runs write other ranges into `out` at the same time
    (a Slurm array task; the Slurm driver passes an empty range): only their half-written scenes are
    removed, whatever machine left them. None: every leftover of a writer not running here.
    hold: where the dataset's writer lock (dotsim.dataset.lock) is entered, before anything is
    written, for as long as the caller keeps it; DatasetBusyError when another writer holds it.
    """
    if split not in SPLITS:
        raise ConfigError(f"--split {split!r}: allowed: train or test")
    if not isinstance(seed, int) or isinstance(seed, bool) or seed < 0:
        raise ConfigError(f"--seed {seed!r}: allowed: an integer >= 0")
    out = check_output_dir(out)
    blender = check_blender(blender)
    record = _run_record(config, split, seed)
    _check_existing_run(out, record)
    has_scenes = (out / dataset.LAYOUT_FILE).exists()
    if has_scenes and dataset.read_layout(out) != config.output.scenes_per_shard:
        raise ConfigError(f"{out}: dataset has scenes_per_shard = {dataset.read_layout(out)}, the config "
                          f"says {config.output.scenes_per_shard}; use the same value or a new --out")
    pattern = config_pattern(config)
    # An unusable asset cache stops the run before anything is written; built-in textures are
    # written below, once the folder is ready.
    cached = split_assets(config, split, out) if config.assets.source == "cache" else None
    software = versions(blender)
    if backend is not None:
        backend.start(out, config)

    out.mkdir(parents=True, exist_ok=True)
    if hold is not None:
        hold.enter_context(writer_lock(out, "dotsim generate"))
    if own is None:
        dataset.remove_partial_scenes(out)
    elif own:
        dataset.remove_partial_scenes_in_range(out, own.start, own.stop, config.output.scenes_per_shard)
    try:
        pattern_file = store_pattern(out, pattern)
    except dataset.FormatError as exc:
        raise ConfigError(f"{exc}; use a new --out directory for a different pattern") from None
    if not (out / RUN_FILE).exists():
        dataset.write_dataset_file(out, RUN_FILE, json_bytes(record))
    assets = cached or split_assets(config, split, out)
    # store_pattern found the file holding this pattern: its bytes now are the ones to check against
    inputs = input_checksums(assets, pattern_file, sha256_file(pattern_file))
    return RenderJob(config, out, split, seed, assets.with_pattern(str(pattern_file), pattern.sha256),
                     pattern_entry(pattern), software, blender, inputs)


def generate(config: Config, out: str | os.PathLike, split: str, scenes: int, start: int = 0,
             workers: int = 1, seed: int = 0, blender: str | None = None,
             progress: bool = True, seal: bool = True, backend=None) -> RunSummary:
    """Render scenes start .. start+scenes-1 of `split` into the dataset `out` (resumable).

    Raises ConfigError before anything is written when an argument, the output directory, the
    Blender executable or an existing dataset in `out` does not fit (see `prepare_run`). Failed
    scenes are listed in the summary (and logged), not raised.

    seal: seal the dataset at the end. False for one of several runs writing into `out` at once (a
    Slurm array task): only this range's half-written scenes are removed, only the shards wholly
    inside the range get their shard.json, and one final `seal_run` seals the dataset.
    backend: renders on other machines instead of `workers` local processes (a
    generator.ray_cluster.RayBackend): `backend.start(out, config)` runs after every check and
    before anything is written, then `backend.render(job, todo, on_results)` renders the scene
    indices `todo`, passing each batch's SceneResults to `on_results` as they come.
    """
    for name, value, low in (("--scenes", scenes, 1), ("--start", start, 0), ("--workers", workers, 1)):
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise ConfigError(f"{name} {value!r}: allowed: an integer >= {low}")
    # One writer per dataset folder, except the runs of disjoint ranges a cluster starts (seal=False).
    with contextlib.ExitStack() as hold:
        return _generate(config, out, split, range(start, start + scenes), workers, seed, blender, progress,
                         seal, backend, hold if seal else None)


def _generate(config: Config, out: str | os.PathLike, split: str, indices: range, workers: int, seed: int,
              blender: str | None, progress: bool, seal: bool, backend, hold) -> RunSummary:
    began = time.perf_counter()
    start, scenes = indices.start, len(indices)
    job = prepare_run(config, out, split, seed, blender, backend, own=None if seal else indices, hold=hold)
    out = job.out

    spp = config.output.scenes_per_shard
    todo = [i for i in indices if not dataset.is_scene_complete(out, i, spp)]
    # A final scene folder only ever appears complete, so one that is not was damaged after the
    # fact (a frame deleted, a bad copy): remove it and render it again.
    damaged = [i for i in todo if dataset.remove_scene(out, i, spp)]
    _unseal(out, todo, spp)
    summary = RunSummary(out=out, skipped=scenes - len(todo), redone=damaged)
    batch = 1 if job.blender is None else max(1, min(BLENDER_BATCH, -(-len(todo) // workers)))
    batches = [todo[k:k + batch] for k in range(0, len(todo), batch)]
    bar = tqdm(total=len(todo), unit="scene", desc=f"generate {split}", disable=not progress,
               dynamic_ncols=True)

    def count(results: list[SceneResult]) -> None:
        for result in results:
            if result.ok:
                summary.done += 1
                summary.frames += result.frames
                summary.worker_seconds += result.seconds
            else:
                summary.failed.append(result.index)
                bar.write(f"scene {result.index} failed: {result.error.strip().splitlines()[-1]}")
        bar.update(len(results))

    if todo and backend is not None:
        backend.render(job, todo, count)
        # A node that died mid-scene left its temp folder there; the scene was redone elsewhere.
        dataset.remove_partial_scenes_in_range(out, start, start + scenes, spp)
    elif todo:
        render_pool(job, batches, min(workers, len(batches)), count)
    bar.close()
    summary.failed.sort()
    # Every run seals (a run killed after its last scene and before or during its seal left a stale
    # seal), which is cheap because sealing is incremental; cluster array tasks (seal=False) seal
    # only their own shards and leave index.json to one final `seal_run` (or `dotsim seal`).
    if seal:
        _seal(summary)
    else:
        _seal_own_shards(out, indices, spp)
    summary.seconds = time.perf_counter() - began
    return summary


def seal_run(config: Config, out: str | os.PathLike, split: str, scenes: int, start: int = 0,
             seed: int = 0) -> RunSummary:
    """Seal what several runs wrote into `out` (the final job of a Slurm array); renders nothing.

    No writer may still be running: every half-written scene is removed. Scenes of start ..
    start+scenes-1 still missing are listed in the summary's `failed` (a rerun of the same range
    renders them); the dataset is sealed by dotsim.dataset.seal_dataset. Raises ConfigError when
    `out` holds no dataset of these settings.
    """
    began = time.perf_counter()
    out = Path(out).absolute()
    if not (out / RUN_FILE).is_file():
        raise ConfigError(f"--out {out}: no {RUN_FILE} (no dataset was started here); check --out")
    _check_existing_run(out, _run_record(config, split, seed))
    with writer_lock(out, "dotsim generate --seal-only"):
        dataset.remove_partial_scenes(out, include_live=True)
        spp = config.output.scenes_per_shard
        summary = RunSummary(out=out)
        for index in range(start, start + scenes):
            if dataset.is_scene_complete(out, index, spp):
                summary.skipped += 1
            else:
                summary.failed.append(index)
        _seal(summary)
    summary.seconds = time.perf_counter() - began
    return summary


def _unseal(out: Path, todo: list[int], scenes_per_shard: int) -> None:
    """Drop the scenes about to be rendered from the shard.json files that still list them (removed
    as damaged above, or by hand): a sealed scene is never sealed again with other bytes, so its
    old entry goes before the scene is written anew. Raises FormatError when another scene of such
    a shard changed after it was sealed (`dotsim verify --repair` removes it)."""
    vouched = vouched_shards(out)
    for shard_index in sorted({index // scenes_per_shard for index in todo}):
        shard = out / dataset.shard_name(shard_index)
        try:
            sealed = json.loads((shard / dataset.SHARD_FILE).read_bytes())["scenes"]
            listed = {scene["name"] for scene in sealed}
        except (OSError, ValueError, KeyError, TypeError):
            continue  # no shard.json (or none readable): nothing sealed to drop
        if any(dataset.scene_name(i) in listed for i in todo if i // scenes_per_shard == shard_index):
            seal_shard(shard, shard_index, scenes_per_shard, vouched.get(shard.name))


def _seal_own_shards(out: Path, indices: range, scenes_per_shard: int) -> None:
    """Seal the shards that lie wholly inside `indices` (no other run writes there): their frames
    are hashed here, on this run's machine while they are likely still cached, so the final seal
    of the dataset only lists them instead of hashing every frame in one process."""
    for shard_index in range(-(-indices.start // scenes_per_shard), indices.stop // scenes_per_shard):
        shard = out / dataset.shard_name(shard_index)
        if shard.is_dir():
            seal_shard(shard, shard_index, scenes_per_shard)


def _seal(summary: RunSummary) -> None:
    """Seal summary.out when it has scenes; other writers still changing it are noted, not raised
    (their own seals, or a later `dotsim seal`, will follow)."""
    if (summary.out / dataset.LAYOUT_FILE).exists():  # the layout comes with the first scene
        try:
            dataset.seal_dataset(summary.out)
        except dataset.DatasetChangingError as exc:
            summary.unsealed = str(exc)


def main_summary(summary: RunSummary) -> int:
    """Print the summary line; exit status 1 when any scene failed."""
    print(summary.line(), file=sys.stderr if summary.failed else sys.stdout)
    return 1 if summary.failed else 0
