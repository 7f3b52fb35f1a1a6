"""The generator run: config -> pattern and textures -> W render workers -> post-render -> shards.

`generate()` validates everything before it writes anything (config values, output directory,
Blender executable, an existing dataset's config), then:
  1. removes partial scenes left by a crashed run and skips complete ones (resume);
  2. writes the projector pattern once (DATASET/pattern.png) and the built-in textures it needs;
  3. renders the remaining scenes in W spawned worker processes: each worker holds one
     SceneRenderer (bpy is imported only there) for all its scenes, or, with `blender=EXE`, runs
     `EXE --background --python generator/blender/run_in_blender.py -- SPEC.json... --out DIR` per
     batch of scenes and reads the raw passes it writes;
  4. post-renders each frame (generator.post_render) and writes the scene atomically
     (dotsim.dataset.write_scene); a failing scene is logged (DATASET/logs/scene_NNNNNNN.log, with
     its traceback) and the run goes on;
  5. seals the dataset (dotsim.dataset.finalize_dataset) and returns a RunSummary.
Scene k is sampled from (config, k, base seed) alone, so the output does not depend on W.
"""

from __future__ import annotations

import concurrent.futures
import importlib.metadata
import json
import multiprocessing
import os
import platform
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

import dotsim
from dotsim import dataset
from dotsim.patterns import DotPattern, PatternError, generate_dot_pattern, load_pattern
from generator.config import Config, ConfigError, check_output_dir
from generator.post_render import RAW_PASSES, make_frame
from generator.scene_spec import (
    MeshAsset,
    SceneResources,
    TextureAsset,
    build_rig,
    frame_sensor_rng,
    sample_scene_spec,
)

RUN_FILE = "generate.json"
TEXTURE_DIR = "textures"
LOG_DIR = "logs"
BUILTIN_TEXTURES_PER_FAMILY = 4
RUN_IN_BLENDER = Path(__file__).resolve().parent / "blender" / "run_in_blender.py"
# Scenes per `blender` call: large enough to amortise Blender's start-up (seconds), small enough
# that the progress bar moves and a crash loses little.
BLENDER_BATCH = 8
_SPLIT_CODE = {"train": 0, "test": 1}


@dataclass
class SceneResult:
    """Outcome of one scene in a worker; seconds: the worker's time on it (render to write)."""
    index: int
    ok: bool
    frames: int = 0
    seconds: float = 0.0
    error: str = ""


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

    def line(self) -> str:
        per_scene = (f"{self.seconds / self.done:.2f} s/scene; {self.worker_seconds / self.done:.2f} s of "
                     "one worker's time each" if self.done else "no scene rendered")
        scenes = "scene" if self.done == 1 else "scenes"
        text = (f"{self.done} {scenes} rendered ({self.frames} frames), {self.skipped} already complete, "
                f"{len(self.failed)} failed, in {self.seconds:.1f} s ({per_scene}) -> {self.out}")
        if self.failed:
            text += f"; failed scenes {self.failed[:10]}{' ...' if len(self.failed) > 10 else ''}, " \
                    f"tracebacks in {self.out / LOG_DIR}"
        return text


# ----------------------------------------------------------------------------- resources


def make_pattern(config: Config, width: int, height: int) -> DotPattern:
    """The projector pattern of a config at the projector resolution (width x height px).

    A pattern file of another size is resampled (area averaging when shrinking), so one captured
    full-resolution pattern serves scaled-down rigs.
    """
    pc = config.pattern
    if pc.source == "procedural":
        return generate_dot_pattern(width, height, density=pc.density, min_spacing=pc.min_spacing,
                                    dot_sigma=pc.dot_sigma, seed=pc.seed)
    pattern = load_pattern(pc.path)
    if pattern.image.shape == (height, width):
        return pattern
    shrinking = pattern.image.shape[1] > width
    image = cv2.resize(pattern.image.astype(np.float32), (width, height),
                       interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    return DotPattern(image=np.clip(image, 0.0, 1.0), centres=None, source=pattern.source,
                      params={**pattern.params, "resampled_from": list(pattern.image.shape[::-1])})


def builtin_textures(out: Path, split: str) -> tuple[TextureAsset, ...]:
    """Procedural reflectance textures (assets_manifest families) under DATASET/textures, made once.

    Each split draws its own seeds, so train and test never share a texture; files that exist are
    reused (same name = same family, index and split = same image).
    """
    from assets_manifest.images import png_bytes, texture_from_image
    from assets_manifest.params import sample_params
    from assets_manifest.procedural_textures import TEXTURE_FAMILIES

    folder = out / TEXTURE_DIR
    folder.mkdir(parents=True, exist_ok=True)
    textures = []
    for family_index, (family_name, family) in enumerate(sorted(TEXTURE_FAMILIES.items())):
        for k in range(BUILTIN_TEXTURES_PER_FAMILY):
            path = folder / f"{split}_{family_name}_{k}.png"
            if not path.exists():
                rng = np.random.default_rng((_SPLIT_CODE[split], family_index, k))
                image = family.make(sample_params({}, family.defaults, rng), rng)
                dataset.atomic_write_bytes(path, png_bytes(texture_from_image(image)))
            textures.append(TextureAsset(str(path)))
    return tuple(textures)


def cached_assets(config: Config, split: str) -> SceneResources:
    """Meshes and textures of `split` from the asset cache ([assets] cache_dir), without pattern
    fields (filled in by the caller). Raises ConfigError naming the cache when it is not usable."""
    from assets_manifest.cache import AssetCacheError, load_asset_cache

    where = f"{config.source}: [assets] cache_dir = {config.assets.cache_dir!r}"
    try:
        cache = load_asset_cache(config.assets.cache_dir, split)
    except AssetCacheError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if not cache.meshes:
        raise ConfigError(f"{where}: the {split} split has no meshes; allowed: a cache built with "
                          'meshes, or source = "primitives"')
    meshes = []
    for entry in cache.meshes:
        with np.load(entry.path) as arrays:
            extent = float(np.ptp(arrays["vertices"], axis=0).max())
        meshes.append(MeshAsset(entry.path, entry.id, extent, tuple(entry.scale_hint)))
    textures = tuple(TextureAsset(entry.path, tuple(entry.scale_hint)) for entry in cache.textures)
    return SceneResources("", "", textures, tuple(meshes), cache.clutter_density)


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


# ----------------------------------------------------------------------------- workers


@dataclass(frozen=True)
class _Job:
    """Everything a worker needs (picklable; sent once to each spawned worker)."""
    config: Config
    out: Path
    split: str
    seed: int
    resources: SceneResources
    pattern_meta: dict
    versions: dict
    blender: str | None


_WORKER: dict = {}


def _init_worker(job: _Job) -> None:
    # Ctrl-C reaches the whole process group; the parent decides (it terminates the workers), so a
    # render is never interrupted half-way inside Blender, which swallows the exception and goes on.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    _WORKER["job"] = job
    if job.blender is None:
        # spawn copies the parent's sys.path; a parent that already imported bpy (a test session, the
        # Blender addon) has Blender's script folders on it, where `import bpy` would find Blender's
        # inner bpy package instead of the module and fail with "No module named '_bpy'".
        sys.path[:] = [p for p in sys.path if f"{os.sep}bpy{os.sep}" not in p]
        try:
            # The only place the pipeline touches bpy: one renderer per worker process, reused.
            from generator.blender.render import SceneRenderer
            _WORKER["renderer"] = SceneRenderer()
        except Exception:
            # Raising here would break the whole pool without a traceback; fail each scene instead.
            _WORKER["start_error"] = traceback.format_exc()


def scene_meta(job: _Job, spec_dict: dict) -> dict:
    """scene.json content (the writer adds format/version/frame fields). Paths of files inside the
    dataset (textures) are stored relative to it, so a dataset can move and two runs of the same
    config and seed give identical metadata wherever they were written."""
    objects = json.loads(json.dumps(spec_dict["objects"]))
    for obj in objects:
        texture = obj["material"]["texture"]
        if texture is not None and Path(texture["path"]).is_relative_to(job.out):
            texture["path"] = Path(texture["path"]).relative_to(job.out).as_posix()
    return {"split": job.split, "seed": spec_dict["seed"], "base_seed": job.seed,
            "config": job.config.to_dict(), "rig": spec_dict["rig"], "pattern": job.pattern_meta,
            "poses": spec_dict["poses"], "objects": objects, "lights": spec_dict["lights"],
            "projector": spec_dict["projector"], "flood": spec_dict["flood"], "world": spec_dict["world"],
            "render": spec_dict["render"], "versions": job.versions}


def _finish_scene(job: _Job, spec_dict: dict, raw_frames: list[dict]) -> int:
    """Post-render the raw frames of one scene and write it; returns the number of frames."""
    index = spec_dict["scene_index"]
    if len(raw_frames) != len(spec_dict["poses"]):
        raise ValueError(f"scene {index}: renderer returned {len(raw_frames)} frames for "
                         f"{len(spec_dict['poses'])} poses")
    rig = build_rig(job.config)
    frames = [make_frame(raw, rig, job.config, frame_sensor_rng(job.seed, index, k),
                         where=f"scene {index} frame {k}")
              for k, raw in enumerate(raw_frames)]
    dataset.write_scene(job.out, index, scene_meta(job, spec_dict), frames,
                        scenes_per_shard=job.config.output.scenes_per_shard)
    return len(frames)


def _log_failure(job: _Job, index: int, text: str) -> None:
    log_dir = job.out / LOG_DIR
    log_dir.mkdir(exist_ok=True)
    dataset.atomic_write_bytes(log_dir / f"{dataset.scene_name(index)}.log", text.encode())


def _clear_failure_log(job: _Job, index: int) -> None:
    (job.out / LOG_DIR / f"{dataset.scene_name(index)}.log").unlink(missing_ok=True)


def _spec_dict(job: _Job, index: int) -> dict:
    return sample_scene_spec(job.config, index, job.seed, job.split, job.resources).to_dict()


def _render_in_process(indices: list[int]) -> list[SceneResult]:
    job, renderer = _WORKER["job"], _WORKER["renderer"]
    results = []
    for index in indices:
        start = time.perf_counter()
        try:
            spec = _spec_dict(job, index)
            frames = _finish_scene(job, spec, renderer.render(spec))
            _clear_failure_log(job, index)
            results.append(SceneResult(index, True, frames, time.perf_counter() - start))
        except Exception:
            _log_failure(job, index, traceback.format_exc())
            results.append(SceneResult(index, False, error=traceback.format_exc(limit=1)))
    return results


def read_raw_npz(path: Path, frame_count: int) -> list[dict[str, np.ndarray]]:
    """Raw frames from run_in_blender.py's npz: arrays named PASS_K (pass name, frame index)."""
    with np.load(path) as data:
        return [{name: data[f"{name}_{k}"] for name in RAW_PASSES} for k in range(frame_count)]


def _render_with_blender(indices: list[int]) -> list[SceneResult]:
    job = _WORKER["job"]
    start = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory(prefix="dotsim-blender-") as tmp:
        tmp = Path(tmp)
        specs = {index: _spec_dict(job, index) for index in indices}
        spec_paths = []
        for index, spec in specs.items():
            spec_paths.append(tmp / f"{dataset.scene_name(index)}.json")
            spec_paths[-1].write_text(json.dumps(spec))
        command = [job.blender, "--background", "--factory-startup", "--python", str(RUN_IN_BLENDER),
                   "--", *map(str, spec_paths), "--out", str(tmp)]
        proc = subprocess.run(command, capture_output=True, text=True)
        blender_share = (time.perf_counter() - start) / len(indices)
        for index, spec in specs.items():
            raw_path = tmp / f"{dataset.scene_name(index)}_raw.npz"
            scene_start = time.perf_counter()
            try:
                if not raw_path.exists():
                    raise RuntimeError(f"blender wrote no {raw_path.name} (exit code {proc.returncode}); "
                                       f"command: {' '.join(command)}\n--- stdout ---\n{proc.stdout[-4000:]}"
                                       f"\n--- stderr ---\n{proc.stderr[-4000:]}")
                frames = _finish_scene(job, spec, read_raw_npz(raw_path, len(spec["poses"])))
                _clear_failure_log(job, index)
                results.append(SceneResult(index, True, frames,
                                           blender_share + time.perf_counter() - scene_start))
            except Exception:
                _log_failure(job, index, traceback.format_exc())
                results.append(SceneResult(index, False, error=traceback.format_exc(limit=1)))
    return results


def render_scenes(job: _Job, indices: list[int]) -> list[SceneResult]:
    """Render scenes `indices` of `job` into its dataset from any process (a Ray task).

    The process keeps its renderer for every later call, as a pool worker does (a renderer serves
    any job: each spec carries everything). A scene already complete (written by an attempt that
    died before reporting back) is not rendered again: a retried batch neither fails on it nor
    writes it twice.
    """
    if _WORKER.get("job") != job:
        if job.blender is None and "renderer" in _WORKER:
            _WORKER["job"] = job
        else:
            _WORKER.clear()
            _init_worker(job)
    spp = job.config.output.scenes_per_shard
    done = [i for i in indices if dataset.is_scene_complete(job.out, i, spp)]
    results = [SceneResult(i, True, len(dataset.read_scene_meta(dataset.scene_dir(job.out, i, spp),
                                                                  verify=False)["frames"]))
               for i in done]
    todo = [i for i in indices if i not in done]
    return results + (_render_batch(todo) if todo else [])


def _render_batch(indices: list[int]) -> list[SceneResult]:
    if "start_error" in _WORKER:
        text = f"the render worker could not start:\n{_WORKER['start_error']}"
        for index in indices:
            _log_failure(_WORKER["job"], index, text)
        return [SceneResult(index, False, error=text) for index in indices]
    if _WORKER["job"].blender is None:
        return _render_in_process(indices)
    return _render_with_blender(indices)


# ----------------------------------------------------------------------------- the run


def batch_failed(job: _Job, indices: list[int], exc: BaseException) -> list[SceneResult]:
    """Results (and logs) for a batch whose worker died: every scene of it failed."""
    text = "".join(traceback.format_exception(exc))
    for index in indices:
        _log_failure(job, index, f"worker process failed:\n{text}")
    return [SceneResult(index, False, error=text) for index in indices]


def count_results(results: list[SceneResult], summary: RunSummary, bar: tqdm) -> None:
    """Add a batch's results to the run summary and the progress bar."""
    for result in results:
        if result.ok:
            summary.done += 1
            summary.frames += result.frames
            summary.worker_seconds += result.seconds
        else:
            summary.failed.append(result.index)
            bar.write(f"scene {result.index} failed: {result.error.strip().splitlines()[-1]}")
    bar.update(len(results))


def _render_all(job: _Job, batches: list[list[int]], workers: int, summary: RunSummary, bar: tqdm) -> None:
    """Render the batches in `workers` spawned processes, counting results into `summary`.

    Ctrl-C cancels the scenes not yet started and terminates the workers at once (the default
    executor shutdown would render every queued scene first); the next run removes the scenes
    they left half-written.
    """
    pool = concurrent.futures.ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                                                  initializer=_init_worker, initargs=(job,))
    try:
        futures = {pool.submit(_render_batch, b): b for b in batches}
        for future in concurrent.futures.as_completed(futures):
            try:
                results = future.result()
            except Exception as exc:  # a worker died (crash in Blender): its scenes failed
                results = batch_failed(job, futures[future], exc)
            count_results(results, summary, bar)
    except KeyboardInterrupt:
        pool.shutdown(wait=False, cancel_futures=True)
        for worker in multiprocessing.active_children():
            worker.terminate()
        raise
    pool.shutdown()


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


def seal_dataset(out: Path) -> None:
    """Write the dataset's index (the one place generation seals, from a run or a Slurm final job)."""
    dataset.finalize_dataset(out)


def prepare_run(config: Config, out: str | os.PathLike, split: str, seed: int = 0,
                blender: str | None = None, backend=None) -> _Job:
    """Check everything about a run, then write what all its scenes share into `out`: the pattern,
    built-in textures and the run record (generate.json). Returns the job the workers get.

    Raises ConfigError before anything is written when an argument, the output directory, the
    Blender executable or an existing dataset in `out` does not fit. backend: see `generate`.
    """
    if split not in _SPLIT_CODE:
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
    rig = build_rig(config)
    try:
        pattern = make_pattern(config, rig.projector.width, rig.projector.height)
    except PatternError as exc:
        raise ConfigError(f"{config.source}: [pattern]: {exc}") from None
    assets = cached_assets(config, split) if config.assets.source == "cache" else None
    software = versions(blender)
    if backend is not None:
        backend.start(out, config)

    out.mkdir(parents=True, exist_ok=True)
    try:
        pattern_file = dataset.store_pattern(out, pattern)
    except dataset.FormatError as exc:
        raise ConfigError(f"{exc}; use a new --out directory for a different pattern") from None
    if not (out / RUN_FILE).exists():
        record_bytes = (json.dumps(record, indent=2, sort_keys=True) + "\n").encode()
        dataset.write_dataset_file(out, RUN_FILE, record_bytes)
    if assets is None:
        assets = SceneResources("", "", textures=builtin_textures(out, split))
    resources = replace(assets, pattern_path=str(pattern_file), pattern_sha256=pattern.sha256)
    return _Job(config, out, split, seed, resources, dataset.pattern_entry(pattern), software, blender)


def generate(config: Config, out: str | os.PathLike, split: str, scenes: int, start: int = 0,
             workers: int = 1, seed: int = 0, blender: str | None = None,
             progress: bool = True, backend=None, seal: bool = True) -> RunSummary:
    """Render scenes start .. start+scenes-1 of `split` into the dataset `out` (resumable).

    Raises ConfigError before anything is written when an argument, the output directory, the
    Blender executable or an existing dataset in `out` does not fit. Failed scenes are listed in the
    summary (and logged), not raised.

    backend: renders on other machines instead of `workers` local processes (a
    generator.ray_cluster.RayBackend): `backend.start(out, config)` runs after every check and before
    anything is written (it raises ConfigError when its workers cannot see `out`), then
    `backend.render(job, todo, summary, bar)` renders the scene indices `todo`.
    seal: False for one of several runs writing into `out` at the same time (a Slurm array task):
    only this range's half-written scenes are removed, and sealing is left to `seal_run`.
    """
    for name, value, low in (("--scenes", scenes, 1), ("--start", start, 0), ("--workers", workers, 1)):
        if not isinstance(value, int) or isinstance(value, bool) or value < low:
            raise ConfigError(f"{name} {value!r}: allowed: an integer >= {low}")
    job = prepare_run(config, out, split, seed, blender, backend)
    out = job.out
    began = time.perf_counter()
    spp = config.output.scenes_per_shard
    if seal:
        dataset.remove_partial_scenes(out)
    else:
        dataset.remove_partial_scenes_in_range(out, start, start + scenes, spp)

    indices = range(start, start + scenes)
    todo = [i for i in indices if not dataset.is_scene_complete(out, i, spp)]
    summary = RunSummary(out=out, skipped=scenes - len(todo))
    batch = 1 if blender is None else max(1, min(BLENDER_BATCH, -(-len(todo) // workers)))
    batches = [todo[k:k + batch] for k in range(0, len(todo), batch)]
    bar = tqdm(total=len(todo), unit="scene", desc=f"generate {split}", disable=not progress,
               dynamic_ncols=True)
    if todo and backend is not None:
        backend.render(job, todo, summary, bar)
        # A node that died mid-scene left its temp dir; the scene was redone elsewhere.
        dataset.remove_partial_scenes_in_range(out, start, start + scenes, spp)
    elif todo:
        _render_all(job, batches, min(workers, len(batches)), summary, bar)
    bar.close()
    summary.failed.sort()
    # finalize re-hashes every file: skip it when nothing changed since the last sealed run.
    changed = summary.done or not (out / dataset.INDEX_FILE).exists()
    if seal and changed and (out / dataset.LAYOUT_FILE).exists():  # the layout comes with the first scene
        seal_dataset(out)
    summary.seconds = time.perf_counter() - began
    return summary


def seal_run(config: Config, out: str | os.PathLike, split: str, scenes: int, start: int = 0,
             seed: int = 0) -> RunSummary:
    """Seal what several runs wrote into `out` (the final job of a Slurm array); renders nothing.

    No writer may still be running: every half-written scene is removed. Scenes of start ..
    start+scenes-1 that are still missing are listed in the summary's `failed` (a rerun of the
    same range renders them). Raises ConfigError when `out` holds no dataset of these settings.
    """
    out = Path(out).absolute()
    if not (out / RUN_FILE).is_file():
        raise ConfigError(f"--out {out}: no {RUN_FILE} (no dataset was started here); check --out")
    _check_existing_run(out, _run_record(config, split, seed))
    began = time.perf_counter()
    dataset.remove_partial_scenes(out, include_live=True)
    spp = config.output.scenes_per_shard
    summary = RunSummary(out=out)
    for index in range(start, start + scenes):
        if dataset.is_scene_complete(out, index, spp):
            summary.skipped += 1
        else:
            summary.failed.append(index)
    if (out / dataset.LAYOUT_FILE).exists():
        seal_dataset(out)
    summary.seconds = time.perf_counter() - began
    return summary


def main_summary(summary: RunSummary) -> int:
    """Print the summary line; exit status 1 when any scene failed."""
    print(summary.line(), file=sys.stderr if summary.failed else sys.stdout)
    return 1 if summary.failed else 0
