"""Render SceneSpec JSON files into raw-pass .npz files, inside Blender or with bpy as a module.

    blender --background --factory-startup --python generator/blender/run_in_blender.py -- \
        SPEC.json [SPEC.json ...] --out DIR
    python generator/blender/run_in_blender.py SPEC.json [...] --out DIR      (bpy from pip)

For each SPEC.json it writes DIR/<SPEC stem>_raw.npz (atomically, dotsim.file_io) holding
float32 arrays PASS_K for PASS in the raw passes of the spec's frame recipe (frame_recipe.py:
projector, flood, ambient, depth, projector_direct, flood_direct) and frame K = 0.. (one per pose).
Blender's own Python has only bpy, numpy and the standard library, so this script and everything
it imports (generator/blender/, dotsim.file_io) use nothing else; it puts the repository root on
sys.path itself.
A spec that fails is reported on stderr and the others still render; the exit code is 1 if any
failed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import traceback
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[2]


def _arguments(argv: list[str]) -> argparse.Namespace:
    # Blender passes its own arguments too; ours follow "--".
    if "--" in argv:
        argv = argv[argv.index("--") + 1 :]
    parser = argparse.ArgumentParser(
        prog="run_in_blender.py",
        description="Render SceneSpec JSON files with Cycles into DIR/<spec stem>_raw.npz "
        "(arrays projector_K, flood_K, ambient_K, depth_K per frame K).",
    )
    parser.add_argument("specs", nargs="+", type=Path, help="SceneSpec JSON files (docs/SCENE_SPEC.md)")
    parser.add_argument("--out", type=Path, required=True, help="output folder (created if missing)")
    return parser.parse_args(argv)


def main(argv: list[str]) -> int:
    args = _arguments(argv)
    if str(REPO_ROOT) not in sys.path:
        sys.path.insert(0, str(REPO_ROOT))
    import numpy as np

    from dotsim.file_io import atomic_writer
    from generator.blender.render import SceneRenderer
    from generator.scene_spec import SceneSpec

    args.out.mkdir(parents=True, exist_ok=True)
    failures = 0
    start = time.perf_counter()
    renderer = SceneRenderer()
    try:
        for spec_path in args.specs:
            try:
                spec = SceneSpec.from_dict(json.loads(spec_path.read_text()))
                frames = renderer.render(spec)
                arrays = {f"{name}_{k}": frame[name] for k, frame in enumerate(frames) for name in frame}
                with atomic_writer(args.out / f"{spec_path.stem}_raw.npz") as stream:
                    np.savez(stream, **arrays)
                print(f"rendered {spec_path} ({len(frames)} frames)", flush=True)
            except Exception:
                failures += 1
                print(f"FAILED {spec_path}:\n{traceback.format_exc()}", file=sys.stderr, flush=True)
    finally:
        renderer.close()
    print(
        f"run_in_blender: {len(args.specs) - failures} of {len(args.specs)} specs rendered, "
        f"{failures} failed, {time.perf_counter() - start:.1f} s",
        flush=True,
    )
    return 1 if failures else 0


if __name__ == "__main__":
    code = main(sys.argv[1:])
    # Inside Blender, sys.exit from a --python script ends Blender with that code.
    sys.exit(code)
