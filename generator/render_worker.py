"""What every render worker does: `render_scenes(job, indices)` renders scenes into a dataset, here
in this process.

A RenderJob is everything a scene needs besides its index; `generator.engines.steps.prepare_run`
makes one (and gets the dataset folder ready). Every engine (the Executor protocol:
generator/run_request.py) hands out indices to processes that call `render_scenes` on their share: a
local pool worker (generator/engines/local_pool.py), a Ray task, a Slurm array task. For each index
the scene is sampled (generator/sample_scene.py), rendered (bpy as a module: one SceneRenderer per
process, reused; or with `job.blender`: `EXE --background --python
generator/blender/run_in_blender.py` per batch), post-rendered (generator/post_render.py) and
written atomically (dotsim.dataset.write_scene). A failing scene is logged
(DATASET/logs/scene_NNNNNNN.log, with its traceback) and reported in its SceneResult, never raised.
Scene k depends only on (config, k, base seed), so the dataset does not depend on who renders what.
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
import time
import traceback
from collections.abc import Iterable
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from dotsim import dataset
from dotsim.file_io import DiskFullError, atomic_write_bytes, map_in_threads
from dotsim.process_lifetime import exec_dies_with_parent
from generator.config import Config
from generator.post_render import frame_channels, make_frame, raw_pass_names
from generator.resources import check_inputs
from generator.sample_scene import SceneResources, frame_streams, sample_scene_spec
from generator.scene_spec import AssetMesh, SceneSpec

LOG_DIR = "logs"
RUN_IN_BLENDER = Path(__file__).resolve().parent / "blender" / "run_in_blender.py"


@dataclass(frozen=True)
class RenderJob:
    """Everything rendering a scene of a dataset needs besides its index (picklable).

    out: the dataset folder (prepared: pattern stored, textures written); seed: the base seed;
    pattern_meta: the pattern entry recorded in every scene.json; versions: software versions
    recorded there; blender: a Blender executable, or None for bpy as a module; inputs: path ->
    recorded sha256 of the files a render reads (generator.resources.input_checksums), checked
    before each scene is rendered.
    """
    config: Config
    out: Path
    split: str
    seed: int
    resources: SceneResources
    pattern_meta: dict
    versions: dict
    blender: str | None
    inputs: dict = field(default_factory=dict)


@dataclass
class SceneResult:
    """Outcome of one scene; seconds: the time spent on it (render to write)."""
    index: int
    ok: bool
    frames: int = 0
    seconds: float = 0.0
    error: str = ""


def render_scenes(job: RenderJob, indices: Iterable[int]) -> list[SceneResult]:
    """Render scenes `indices` of `job` into `job.out`, here in this process; one SceneResult each.

    With bpy as a module the first call makes this process's SceneRenderer (a factory-reset bpy
    session) and later calls reuse it, so call it in a process of its own (a pool worker, a Ray or
    Slurm task), not in one holding Blender data it needs. A scene already complete is reported
    done and not rendered again: a retried task (its node died after writing some of its scenes)
    neither fails on them nor writes them twice. Seal the dataset afterwards
    (`dotsim.dataset.seal_dataset`; incremental, so sealing after every share is cheap).
    """
    spp = job.config.output.scenes_per_shard
    done, todo = [], []
    for index in indices:
        (done if dataset.is_scene_complete(job.out, index, spp) else todo).append(index)
    results = [SceneResult(index, True, _frame_count(job, index)) for index in done]
    if not todo:
        return results
    if job.blender is not None:
        return results + _render_with_blender(job, todo)
    renderer = process_renderer()
    if isinstance(renderer, str):
        return results + failed_batch(job, todo, f"the render worker could not start:\n{renderer}")
    return results + [_render_in_process(job, renderer, index) for index in todo]


def failed_batch(job: RenderJob, indices: list[int], text: str) -> list[SceneResult]:
    """Log `text` as the failure of every scene of `indices` (a worker, task or node that died or
    could not start); their failed SceneResults."""
    for index in indices:
        _log_failure(job, index, text)
    return [SceneResult(index, False, error=text) for index in indices]


def scene_meta(job: RenderJob, spec: SceneSpec) -> dict:
    """scene.json content (the writer adds format/version/frame fields). Paths of files inside the
    dataset (textures) are stored relative to it, so a dataset can move and two runs of the same
    config and seed give identical metadata wherever they were written."""
    objects = []
    for obj in spec.objects:
        texture = obj.material.texture
        if texture is not None and Path(texture.path).is_relative_to(job.out):
            texture = replace(texture, path=Path(texture.path).relative_to(job.out).as_posix())
            obj = replace(obj, material=replace(obj.material, texture=texture))
        objects.append(obj)
    stored = replace(spec, objects=tuple(objects)).to_dict()
    colour = {"colour_camera": stored["colour_camera"]} if "colour_camera" in stored else {}
    return {"split": job.split, "seed": spec.seed, "base_seed": job.seed, "config": job.config.to_dict(),
            "rig": stored["rig"], "pattern": job.pattern_meta, "poses": stored["poses"],
            "objects": stored["objects"], "lights": stored["lights"], "projector": stored["projector"],
            "flood": stored["flood"], "world": stored["world"], "render": stored["render"],
            "versions": job.versions} | colour


def read_raw_npz(path: Path, spec: SceneSpec) -> list[dict[str, np.ndarray]]:
    """The raw frames of `spec` from run_in_blender.py's npz: arrays named PASS_K (raw pass name,
    frame index)."""
    with np.load(path) as data:
        return [{name: data[f"{name}_{k}"] for name in raw_pass_names(spec)} for k in range(len(spec.poses))]


def _sample(job: RenderJob, index: int) -> SceneSpec:
    """Scene `index`'s spec, once every input file it reads still has its recorded sha256."""
    spec = sample_scene_spec(job.config, index, job.seed, job.split, job.resources)
    check_inputs(job.inputs, spec_inputs(spec))
    return spec


def spec_inputs(spec: SceneSpec) -> list[str]:
    """The files rendering `spec` reads: the pattern, the textures and the asset meshes."""
    files = [spec.pattern.path]
    for obj in spec.objects:
        if obj.material.texture is not None:
            files.append(obj.material.texture.path)
        if isinstance(obj.mesh, AssetMesh):
            files.append(obj.mesh.path)
    return files


def _finish_scene(job: RenderJob, spec: SceneSpec, raw_frames: list[dict]) -> int:
    """Post-render the raw frames of one scene and write it; returns the number of frames."""
    index = spec.scene_index
    if len(raw_frames) != len(spec.poses):
        raise ValueError(f"scene {index}: renderer returned {len(raw_frames)} frames for "
                         f"{len(spec.poses)} poses")
    threads = post_render_threads(job.config)
    frames = map_in_threads(lambda k: make_frame(raw_frames[k], spec, frame_streams(job.seed, spec, k),
                                                 where=f"scene {index} frame {k}"),
                            range(len(raw_frames)), threads)
    dataset.write_scene(job.out, index, scene_meta(job, spec), frames, channels=frame_channels(spec),
                        scenes_per_shard=job.config.output.scenes_per_shard, threads=threads,
                        compression=dataset.EXR_COMPRESSIONS[job.config.output.exr_compression])
    return len(frames)


def post_render_threads(config: Config) -> int:
    """Threads a worker post-renders and encodes a scene's frames in: as many as it renders with
    ([render] threads; 0 = every core), so a worker alone on a machine uses all of it there too.
    Each frame has its own random streams (frame_streams), so the bytes do not depend on it."""
    return config.render.threads or os.cpu_count() or 1


def _frame_count(job: RenderJob, index: int) -> int:
    sdir = dataset.scene_dir(job.out, index, job.config.output.scenes_per_shard)
    return len(dataset.read_scene_meta(sdir, verify=False)["frames"])


def _log_failure(job: RenderJob, index: int, text: str) -> None:
    log_dir = job.out / LOG_DIR
    log_dir.mkdir(exist_ok=True)
    atomic_write_bytes(log_dir / f"{dataset.scene_name(index)}.log", text.encode())


def _clear_failure_log(job: RenderJob, index: int) -> None:
    (job.out / LOG_DIR / f"{dataset.scene_name(index)}.log").unlink(missing_ok=True)


def _render_in_process(job: RenderJob, renderer, index: int) -> SceneResult:
    start = time.perf_counter()
    try:
        spec = _sample(job, index)
        frames = _finish_scene(job, spec, renderer.render(spec))
        _clear_failure_log(job, index)
        return SceneResult(index, True, frames, time.perf_counter() - start)
    except DiskFullError:
        raise  # every later scene would fail too: stop the run (the caller reports it)
    except Exception:
        _log_failure(job, index, traceback.format_exc())
        return SceneResult(index, False, error=traceback.format_exc(limit=1))


def _render_with_blender(job: RenderJob, indices: list[int]) -> list[SceneResult]:
    start = time.perf_counter()
    results = []
    with tempfile.TemporaryDirectory(prefix="dotsim-blender-") as tmp:
        tmp = Path(tmp)
        specs = {index: _sample(job, index) for index in indices}
        spec_paths = []
        for index, spec in specs.items():
            spec_paths.append(tmp / f"{dataset.scene_name(index)}.json")
            spec_paths[-1].write_text(json.dumps(spec.to_dict()))
        command = [job.blender, "--background", "--factory-startup", "--python", str(RUN_IN_BLENDER),
                   "--", *map(str, spec_paths), "--out", str(tmp)]
        proc = subprocess.run(command, capture_output=True, text=True, preexec_fn=exec_dies_with_parent)
        blender_share = (time.perf_counter() - start) / len(indices)
        for index, spec in specs.items():
            raw_path = tmp / f"{dataset.scene_name(index)}_raw.npz"
            scene_start = time.perf_counter()
            try:
                if not raw_path.exists():
                    raise RuntimeError(f"blender wrote no {raw_path.name} (exit code {proc.returncode}); "
                                       f"command: {' '.join(command)}\n--- stdout ---\n{proc.stdout[-4000:]}"
                                       f"\n--- stderr ---\n{proc.stderr[-4000:]}")
                frames = _finish_scene(job, spec, read_raw_npz(raw_path, spec))
                _clear_failure_log(job, index)
                results.append(SceneResult(index, True, frames,
                                           blender_share + time.perf_counter() - scene_start))
            except DiskFullError:
                raise
            except Exception:
                _log_failure(job, index, traceback.format_exc())
                results.append(SceneResult(index, False, error=traceback.format_exc(limit=1)))
    return results


# The process's SceneRenderer, or the traceback of its failed start (bpy as a module).
_PROCESS: dict = {}


def process_renderer():
    """This process's SceneRenderer, made on first use, or the traceback text of why it could not."""
    if not _PROCESS:
        try:
            # The only place the run touches bpy: one renderer per process, reused.
            from generator.blender.render import SceneRenderer
            _PROCESS["renderer"] = SceneRenderer()
        except Exception:
            # Raising here would break a whole pool without a traceback; fail each scene instead.
            _PROCESS["renderer"] = traceback.format_exc()
    return _PROCESS["renderer"]
