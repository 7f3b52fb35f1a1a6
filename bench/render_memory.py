"""Resident memory of one render worker over many scenes (does reusing the bpy scene leak?).

    python -m bench.render_memory [--scenes 1000] [--minutes 10] [--width 160]

One SceneRenderer renders scene after scene, each with its own seed, 100-500 random objects (some
textured primitives, some asset meshes from .npz files, so both mesh caches are exercised), four
poses, extra lights, like a generator worker. RSS (VmRSS) is read after every scene. Stops after
--scenes scenes or --minutes minutes, whichever comes first, and says which.
Goal (issue 3): RSS grows less than 5% after the first 10 scenes (median of the last 50 scenes
against the median of scenes 11-60).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from bench.render_speed import bench_rig, bench_spec, write_inputs
from generator.blender.geometry import primitive_mesh
from generator.scene_spec import SceneSpec


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS in /proc/self/status")


def write_asset_meshes(folder: Path, count: int) -> list[str]:
    """`count` asset .npz files (docs/ASSETS.md format) from primitives with random vertex jitter."""
    rng = np.random.default_rng(1)
    shapes = ("sphere", "torus", "cylinder", "cone")
    paths = []
    for k in range(count):
        mesh = primitive_mesh(shapes[k % len(shapes)], segments=24 + k % 16)
        vertices = mesh.vertices * rng.uniform(0.1, 0.5, 3) + rng.normal(0, 0.003, mesh.vertices.shape)
        uvs = np.zeros((len(vertices), 2), np.float32)
        uvs[mesh.triangles.ravel()] = mesh.corner_uvs
        path = folder / f"asset_{k}.npz"
        np.savez(
            path,
            vertices=vertices.astype(np.float32),
            faces=mesh.triangles,
            uvs=uvs,
            normals=vertices / np.linalg.norm(vertices, axis=1, keepdims=True),
        )
        paths.append(str(path))
    return paths


def memory_summary(history: list[float]) -> dict:
    """RSS statistics that tell growth from noise: RSS moves by tens of MB from scene to scene
    (object counts and caches), so single scenes mislead. Medians of scenes 11-60 ("early") and of
    the last 50 ("late"), their ratio, and the least-squares slope over scenes 11.. in MB per 1000
    scenes."""
    values = np.asarray(history, np.float64)
    after_warmup = values[10:] if len(values) > 20 else values
    early = float(np.median(after_warmup[:50]))
    late = float(np.median(after_warmup[-50:]))
    scenes = np.arange(len(after_warmup))
    slope = float(np.polyfit(scenes, after_warmup, 1)[0] * 1000) if len(after_warmup) > 1 else 0.0
    return {
        "first": float(values[0]),
        "early": early,
        "late": late,
        "growth": late / early - 1,
        "slope_per_1000": slope,
        "max": float(values.max()),
    }


def report(history: list[float], seconds: float, size: str) -> None:
    stats = memory_summary(history)
    for k in sorted({min(n, len(history)) for n in (1, 10, 50, 100, 200, 500, 1000)}):
        print(f"  RSS after scene {k:>5}: {history[k - 1]:7.0f} MB")
    print(
        f"summary: {len(history)} scenes at {size} in {seconds:.0f} s "
        f"({seconds / len(history):.2f} s/scene); "
        f"RSS median of scenes 11-60 {stats['early']:.0f} MB, of the last 50 {stats['late']:.0f} MB "
        f"(growth {100 * stats['growth']:+.1f}%), trend {stats['slope_per_1000']:+.0f} MB per 1000 scenes, "
        f"max {stats['max']:.0f} MB, first scene {stats['first']:.0f} MB"
    )


def poses(rng: np.random.Generator) -> list:
    out = []
    for _ in range(4):
        pose = np.eye(4)
        pose[:3, 3] = rng.normal(0, 0.02, 3)
        out.append(pose.tolist())
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.render_memory", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--scenes", type=int, default=1000, help="scenes to render at most (default 1000)")
    parser.add_argument("--minutes", type=float, default=10.0, help="time limit in minutes (default 10)")
    parser.add_argument("--width", type=int, default=160, help="camera width (default 160)")
    parser.add_argument("--assets", type=int, default=40, help="distinct asset meshes (default 40)")
    args = parser.parse_args(argv)

    from tqdm import tqdm

    from generator.blender.render import SceneRenderer

    rig = bench_rig(args.width)
    history = []
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dotsim-bench-") as tmp, SceneRenderer() as renderer:
        inputs = write_inputs(rig, Path(tmp), n_textures=20)
        assets = write_asset_meshes(Path(tmp), args.assets)
        rng = np.random.default_rng(0)
        progress = tqdm(range(args.scenes), unit="scene")
        for index in progress:
            count = int(rng.integers(100, 501))
            spec = bench_spec(rig, inputs, count, seed=index)
            spec["poses"] = poses(rng)
            for obj in spec["objects"][1::3]:
                obj["mesh"] = {"kind": "asset", "path": assets[int(rng.integers(len(assets)))], "id": "a"}
            renderer.render(SceneSpec.from_dict(spec))
            history.append(rss_mb())
            progress.set_postfix(rss_mb=f"{history[-1]:.0f}")
            if time.perf_counter() - start > 60 * args.minutes:
                progress.close()
                print(f"stopped after {len(history)} scenes: --minutes {args.minutes} reached")
                break
    seconds = time.perf_counter() - start
    report(history, seconds, f"{rig.camera.width}x{rig.camera.height}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
