"""Same frames before and after a change: render the same scenes with another revision's code and with
this checkout's, and compare every frame file byte for byte (sha256).

    python -m bench.same_frames --before a7d8979 [--scenes 3]

A refactor that must not change behaviour (issue 28's rule) proves it here: the tiny config, and the
default config at [rig] scale 0.05 (cached assets, from `make assets-train`; 1 sample), split train,
seed 3. Scenes of both kinds of render recipe are among them (with extra lights and without:
docs/RENDERING.md); the output lists each scene's extra lights. The other revision is unpacked into a
temporary folder (bench.generate_stages.unpack). Both sides run with this interpreter, so only the code
differs. JSON files are left out: scene.json records the config file's path, which differs between
checkouts. Exit status 1 when any frame differs.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from bench.generate_stages import dotsim_command, unpack

REPO = Path(__file__).resolve().parents[1]


def small_default(folder: Path) -> Path:
    """dotsim/configs/default.toml at scale 0.05, with its asset cache made absolute (this checkout's)."""
    cache = (Path.cwd() / "assets_cache").resolve()
    if not (cache / "train" / "index.json").is_file():
        sys.exit(f"{cache}/train: no asset cache; build it with `make assets-train`")
    text = (REPO / "dotsim" / "configs" / "default.toml").read_text()
    text = text.replace("scale = 0.5", "scale = 0.05")
    text = text.replace('cache_dir = "assets_cache"', f'cache_dir = "{cache}"')
    path = folder / "default_small.toml"
    path.write_text(text)
    return path


def render(root: Path, config: str, out: Path, scenes: int) -> None:
    """`dotsim generate` with the code of checkout `root`."""
    command = [*dotsim_command(root), "generate", "--config", config, "--out", str(out),
               "--split", "train", "--scenes", str(scenes), "--seed", "3", "--workers", "1", "--no-progress"]
    subprocess.run(command, cwd=root, env={**os.environ, "PYTHONPATH": str(root)}, check=True,
                   stdout=subprocess.DEVNULL)


def frame_sums(out: Path) -> dict[str, str]:
    """Relative path -> sha256 of every file of a dataset folder but its JSON (which names paths)."""
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(out.rglob("*")) if p.is_file() and p.suffix != ".json" and "logs" not in p.parts}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--before", required=True, help="git revision whose frames this checkout must equal")
    parser.add_argument("--scenes", type=int, default=3, help="scenes per config")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="dotsim-same-frames-") as tmp:
        tmp = Path(tmp)
        before = unpack(args.before, tmp)
        configs = {"tiny": "tiny", "default at scale 0.05": str(small_default(tmp))}
        differ = 0
        for name, config in configs.items():
            sums = {}
            for side, root in (("before", before), ("after", REPO)):
                out = tmp / side / name.split()[0]
                render(root, config, out, args.scenes)
                sums[side] = frame_sums(out)
            scenes = sorted((tmp / "after" / name.split()[0]).glob("shard_*/scene_*/scene.json"))
            lights = [len(json.loads(p.read_text())["lights"]) for p in scenes]
            bad = [k for k in sums["before"].keys() | sums["after"].keys()
                   if sums["before"].get(k) != sums["after"].get(k)]
            differ += len(bad)
            print(f"{name}: {len(sums['after'])} files, extra lights per scene {lights}: "
                  + ("byte-identical" if not bad else f"{len(bad)} DIFFER, e.g. {sorted(bad)[:3]}"))
    print(f"{args.before} -> this checkout: " + ("same frames" if not differ else f"{differ} file(s) differ"))
    return 1 if differ else 0


if __name__ == "__main__":
    sys.exit(main())
