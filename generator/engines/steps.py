"""The steps of a generator run on its dataset folder, the same for every engine
(the Executor protocol: generator/run_request.py): get the folder ready, render what is missing, seal.

  `prepare_run` (an executor's prepare; `prepare_writer` for engines that render their range
     themselves) checks the output directory's existing dataset, the pattern, the asset cache and
     what the engine needs (a cluster that answers, nodes that see the folder), then takes the
     writer lock (dotsim.dataset.lock; a second local writer is refused naming the holder), removes
     partial scenes left by a crashed run, writes the projector pattern once (DATASET/pattern.png),
     the run record (DATASET/generate.json) and the built-in textures it needs
     (generator/resources.py), and notes the sha256 of every input file a render reads, which each
     worker checks before it renders a scene;
  `render_missing` (an executor's render) skips complete scenes (resume), removes damaged ones (a
     frame deleted after the fact) and has the engine render them with the others (each scene
     through generator/render_worker.py: sample, render, post-render, write atomically; a failing
     scene is logged and the run goes on), with a progress bar and the run's summary;
  `seal_written` (an executor's seal) seals the dataset (dotsim.dataset.seal_dataset: incremental,
     so every run seals, and a run killed before its seal leaves nothing a rerun does not mend), or
     only a range's own shards; `seal_run` seals what several range runs wrote (the Slurm sealing
     job).
The engines beside it (generator/engines/local_pool.py, ray_cluster.py, slurm.py) build on these;
generator/driver.py drives a run through its engine.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import json
import platform
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from dotsim import dataset
from dotsim.dataset.lock import writer_lock
from dotsim.dataset.seal import seal_shard, vouched_shards
from dotsim.file_io import json_bytes, sha256_file
from dotsim.pattern_store import pattern_entry, store_pattern
from dotsim.version import __version__
from generator.config import Config, ConfigError
from generator.render_worker import RenderJob, SceneResult
from generator.resources import input_checksums, split_assets
from generator.run_request import RunRequest, RunSummary

RUN_FILE = "generate.json"


def _run_record(config: Config, split: str, seed: int) -> dict:
    """What must stay the same for scenes to belong to one dataset (the config's file name may vary)."""
    settings = config.to_dict()
    settings.pop("source")
    return {"split": split, "base_seed": seed, "config": settings}


def _with_added_defaults(existing: dict, record: dict) -> dict:
    """`existing` (a dataset's generate.json) with the keys and tables a later dotsim added to the
    config, where `record` gives them their default: such a key at its default renders as before it
    existed (e.g. [sensor] speckle_contrast = 0, [rig] stereo = false, the whole [device_depth] table
    with its engine off), so a dataset made before it resumes."""
    defaults = Config().to_dict()
    config = {section: dict(values) if isinstance(values, dict) else values
              for section, values in existing.get("config", {}).items()}
    for section, values in record["config"].items():
        if section not in config and isinstance(values, dict) and values == defaults.get(section):
            config[section] = dict(values)
        elif isinstance(values, dict) and isinstance(config.get(section), dict):
            for key, value in values.items():
                if key not in config[section] and value == defaults.get(section, {}).get(key, object()):
                    config[section][key] = value
    return {**existing, "config": config}


def _check_existing_run(out: Path, record: dict) -> None:
    path = out / RUN_FILE
    if not path.exists():
        return
    try:
        existing = json.loads(path.read_text())
    except ValueError as exc:
        raise ConfigError(f"{path}: unreadable ({exc}); remove it or use a new --out") from None
    existing = _with_added_defaults(existing, record)
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
    return {"dotsim": __version__, "blender": blender_version, "numpy": np.__version__,
            "python": platform.python_version()}


# ----------------------------------------------------------------------------- the run


def prepare_run(request: RunRequest, hold: contextlib.ExitStack | None = None, own: range | None = None,
                engine_check: Callable[[], None] | None = None) -> RenderJob:
    """Get the dataset folder `request.out` ready; the RenderJob that renders its scenes.

    Raises ConfigError before anything is written when an existing dataset in `out`, the pattern or
    the asset cache does not fit the request, or when `engine_check()` raises (an engine's own
    check, run after every other: a cluster that cannot be reached or whose nodes do not see
    `out`). Then removes scenes a crashed run left half-written, stores the pattern and the run
    record (DATASET/generate.json) and writes the built-in textures of the split.

    own: the scenes this run writes while other runs write other ranges into `out` at the same time
    (a Slurm array task; the Slurm driver passes an empty range): only their half-written scenes are
    removed, whatever machine left them. None: every leftover of a writer not running here.
    hold: where the dataset's writer lock (dotsim.dataset.lock) is entered, before anything is
    written, for as long as the caller keeps it; DatasetBusyError when another writer holds it.
    """
    config, out = request.config, request.out
    record = _run_record(config, request.split, request.seed)
    _check_existing_run(out, record)
    has_scenes = (out / dataset.LAYOUT_FILE).exists()
    if has_scenes and dataset.read_layout(out) != config.output.scenes_per_shard:
        raise ConfigError(f"{out}: dataset has scenes_per_shard = {dataset.read_layout(out)}, the config "
                          f"says {config.output.scenes_per_shard}; use the same value or a new --out")
    pattern = request.pattern
    # An unusable asset cache stops the run before anything is written; built-in textures are
    # written below, once the folder is ready.
    cached = split_assets(config, request.split, out) if config.assets.source == "cache" else None
    software = versions(request.blender)
    if engine_check is not None:
        engine_check()

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
    assets = cached or split_assets(config, request.split, out)
    # store_pattern found the file holding this pattern: its bytes now are the ones to check against
    inputs = input_checksums(assets, pattern_file, sha256_file(pattern_file))
    return RenderJob(config, out, request.split, request.seed,
                     assets.with_pattern(str(pattern_file), pattern.sha256), pattern_entry(pattern), software,
                     request.blender, inputs)


def prepare_writer(request: RunRequest, hold: contextlib.ExitStack,
                   engine_check: Callable[[], None] | None = None) -> RenderJob:
    """prepare_run for a run that renders its range itself (local processes, Ray): the dataset's one
    writer (the writer lock, every leftover removed) when it seals, else one of several runs
    writing disjoint ranges at once (no lock; only its range's leftovers removed)."""
    if request.seal:
        return prepare_run(request, hold, None, engine_check)
    return prepare_run(request, None, request.indices, engine_check)


# render_todo(job, todo, on_results): an engine renders the scene indices `todo` of `job`.
RenderTodo = Callable[[RenderJob, list[int], Callable[[list[SceneResult]], None]], None]


def render_missing(request: RunRequest, job: RenderJob, render_todo: RenderTodo) -> RunSummary:
    """Render the scenes of the request's range that are not complete: `render_todo(job, todo,
    on_results)` renders the indices `todo`, passing each batch's SceneResults to `on_results` as
    they come (progress bar, summary). Complete scenes are skipped (resume); damaged ones are
    removed and rendered again."""
    out, spp = job.out, request.config.output.scenes_per_shard
    todo = [i for i in request.indices if not dataset.is_scene_complete(out, i, spp)]
    # A final scene folder only ever appears complete, so one that is not was damaged after the
    # fact (a frame deleted, a bad copy): remove it and render it again.
    damaged = [i for i in todo if dataset.remove_scene(out, i, spp)]
    _unseal(out, todo, spp)
    summary = RunSummary(out=out, skipped=request.scenes - len(todo), redone=damaged)
    bar = tqdm(total=len(todo), unit="scene", desc=f"generate {request.split}", disable=not request.progress,
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

    if todo:
        render_todo(job, todo, count)
    bar.close()
    summary.failed.sort()
    return summary


def seal_written(request: RunRequest, job: RenderJob, summary: RunSummary) -> None:
    """Seal after a run that rendered its range itself. Every run seals (a run killed after its last
    scene and before or during its seal left a stale seal), which is cheap because sealing is
    incremental; range runs (request.seal False, Slurm's array tasks) seal only their own shards
    and leave index.json to one final `seal_run` (or `dotsim seal`)."""
    if request.seal:
        _seal(summary)
    else:
        _seal_own_shards(job.out, request.indices, request.config.output.scenes_per_shard)


def seal_run(request: RunRequest) -> RunSummary:
    """Seal what several runs wrote into `request.out` (the final job of a Slurm array); renders
    nothing.

    No writer may still be running: every half-written scene is removed. Scenes of the request's
    range still missing are listed in the summary's `failed` (a rerun of the same range renders
    them); the dataset is sealed by dotsim.dataset.seal_dataset. Raises ConfigError when `out`
    holds no dataset of these settings.
    """
    began = time.perf_counter()
    out = request.out
    if not (out / RUN_FILE).is_file():
        raise ConfigError(f"--out {out}: no {RUN_FILE} (no dataset was started here); check --out")
    _check_existing_run(out, _run_record(request.config, request.split, request.seed))
    with writer_lock(out, "dotsim generate --seal-only"):
        dataset.remove_partial_scenes(out, include_live=True)
        spp = request.config.output.scenes_per_shard
        summary = RunSummary(out=out)
        for index in request.indices:
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
