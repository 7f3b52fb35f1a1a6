"""Benchmark: building the default asset caches, and building a 500-object scene in Blender from them.

    python -m bench.assets_build [--repeats 3] [--objects 500] [--scenes 4] [--workers N]
                                 [--no-blender] [--cache DIR]

1. Cold build of each shipped split (train, test) into a fresh temp cache, `--repeats` times, and a
   no-op rebuild (incremental: everything reused); medians and their ratio.
2. SceneRenderer.setup (bpy scene construction, no render) of `--objects` objects drawn from the
   test cache (asset meshes + textures): the first scene (meshes read from .npz into bpy) and later
   scenes (meshes cached in bpy), side by side with the same count of built-in primitives.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from assets_manifest.cache import build_asset_cache, default_manifest_path, load_asset_cache
from assets_manifest.manifest import load_manifest


def _timed(fn, *args) -> float:
    start = time.perf_counter()
    fn(*args)
    return time.perf_counter() - start


def _build_quietly(manifest, cache: Path, workers: int) -> None:
    build_asset_cache(manifest, cache, workers=workers, progress=False, log=lambda line: None)


def bench_builds(root: Path, repeats: int, workers: int) -> Path:
    """Time cold and no-op builds of both shipped splits; return the last cache built."""
    cache = root / "cache_0"
    for split in ("train", "test"):
        manifest = load_manifest(default_manifest_path(split))
        cold = []
        for r in range(repeats):
            cache = root / f"cache_{r}"
            cold.append(_timed(_build_quietly, manifest, cache, workers))
        noop = [_timed(_build_quietly, manifest, cache, workers) for _ in range(repeats)]
        size = sum(p.stat().st_size for p in (cache / split).rglob("*") if p.is_file()) / 1e6
        cold_s, noop_s = statistics.median(cold), statistics.median(noop)
        print(
            f"{split}: {len(manifest.meshes)} meshes + {len(manifest.textures)} textures, {size:.0f} MB | "
            f"cold build median {cold_s:.1f} s ({1000 * cold_s / len(manifest.assets):.0f} ms/asset) | "
            f"no-op rebuild median {noop_s:.2f} s | cold/no-op {cold_s / noop_s:.0f}x"
        )
    return cache


def _scene_objects(cache, n: int, seed: int, use_assets: bool, textured: bool) -> list[dict]:
    from generator.blender.demo_scenes import material, primitive

    rng = np.random.default_rng(seed)
    objects = []
    for k in range(n):
        z = rng.uniform(0.8, 4.0)
        x, y = np.tan(rng.uniform(-0.5, 0.5, 2)) * z
        rotation = rng.uniform(0, 2 * math.pi, 3).tolist()
        texture = cache.textures[int(rng.integers(len(cache.textures)))]
        mat = material(
            albedo=float(rng.uniform(0.2, 0.9)),
            texture={
                "path": texture.path,
                "scale": float(rng.uniform(*texture.scale_hint)),
                "contrast": float(rng.uniform(0.3, 1.0)),
            }
            if textured
            else None,
        )
        if use_assets:
            mesh = cache.meshes[int(rng.integers(len(cache.meshes)))]
            size = float(rng.uniform(*mesh.scale_hint))
            objects.append(
                {
                    "name": f"object_{k}",
                    "mesh": {"kind": "asset", "path": mesh.path, "id": mesh.id},
                    "location": [float(x), float(y), float(z)],
                    "rotation_euler": rotation,
                    "scale": [size] * 3,
                    "material": mat,
                }
            )
        else:
            shape = ("box", "sphere", "cylinder", "cone", "torus")[int(rng.integers(5))]
            objects.append(
                primitive(
                    f"object_{k}", shape, rng.uniform(0.05, 0.4, 3), (x, y, z), rotation=rotation, mat=mat
                )
            )
    return objects


def bench_blender(cache_dir: Path, n_objects: int, scenes: int, root: Path) -> None:
    from dotsim.patterns import generate_dot_pattern
    from dotsim.rig.presets import get_preset
    from generator.blender.demo_scenes import base_spec
    from generator.blender.render import SceneRenderer
    from generator.scene_spec import SceneSpec

    cache = load_asset_cache(cache_dir, "test")
    rig = get_preset("structure_core").scaled(0.25)
    pattern = generate_dot_pattern(rig.projector.width, rig.projector.height, density=0.05, seed=0)
    pattern_path = root / "pattern.png"
    pattern.save_png(pattern_path)
    variants = {
        "cache meshes + cache textures": (True, True),
        "cache meshes, untextured": (True, False),
        "primitives + cache textures": (False, True),
        "primitives, untextured": (False, False),
    }
    results = {}
    for label, (use_assets, textured) in variants.items():
        times = []
        with SceneRenderer() as renderer:
            for s in range(scenes):
                spec = base_spec(rig.to_dict(), str(pattern_path), pattern.sha256)
                spec["objects"] = _scene_objects(cache, n_objects, s, use_assets, textured)
                times.append(_timed(renderer.setup, SceneSpec.from_dict(spec)))
        results[label] = times
        print(
            f"blender build, {n_objects} objects, {label}: first scene {times[0]:.2f} s, "
            f"later scenes median {statistics.median(times[1:]):.2f} s"
        )
    baseline = statistics.median(results["primitives, untextured"][1:])
    print(
        "later-scene build time relative to untextured primitives: "
        + ", ".join(f"{label} {statistics.median(t[1:]) / baseline:.1f}x" for label, t in results.items())
    )
    distinct = len({o["mesh"]["path"] for o in _scene_objects(cache, n_objects, 0, True, False)})
    print(f"(a {n_objects}-object scene draws {distinct} distinct meshes of {len(cache.meshes)})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.assets_build", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--repeats", type=int, default=3, help="cold builds per split (default 3)")
    parser.add_argument("--objects", type=int, default=500, help="objects per Blender scene (default 500)")
    parser.add_argument("--scenes", type=int, default=4, help="scenes built per renderer (default 4)")
    parser.add_argument(
        "--workers", type=int, default=os.cpu_count() or 1, help="build processes (default: one per CPU core)"
    )
    parser.add_argument("--no-blender", action="store_true", help="only time the cache builds")
    parser.add_argument(
        "--cache",
        type=Path,
        help="an already built cache: skip the build timings and "
        "build the Blender scenes from its test split",
    )
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="dotsim_bench_assets_") as tmp:
        root = Path(tmp)
        cache = args.cache or bench_builds(root, args.repeats, args.workers)
        if not args.no_blender:
            bench_blender(cache, args.objects, args.scenes, root)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
