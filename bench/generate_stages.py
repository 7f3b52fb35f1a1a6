"""Benchmark: the generator's work around the render, stage by stage, before and after, in one run.

    python -m bench.generate_stages [--sizes 608,1216] [--repeats 3] [--before 7369d4c] [--scene 0]
                                    [--compression]

For each side (`before`: the code of commit --before, unpacked from git into a temporary folder;
`after`: this checkout) and each IR width of --sizes, a child process running that side's code
renders scene --scene of the before side's structure_core.toml (in dotsim/configs/, or configs/ in
older revisions; built-in primitives, so no asset cache is needed; scene 0 has extra lights, so it
takes the direct render too) and measures, per frame:

- render: SceneRenderer.render of the scene (build + its frames), wall and CPU seconds;
- each stage of the work around the render, run one frame after another in one thread and timed
  with cProfile (the functions make_frame and write_scene call: exposure, sensor model, masks,
  ground truth, the checks of the frame, encoding, hashing, writing); their sum;
- all-in work: generator.render_worker._finish_scene, the generator's own path from raw passes to
  a written scene (the after side post-renders and encodes a scene's frames in as many threads as
  it renders with), wall and CPU seconds, and its share of the render;
- MB per scene on disk, and reading the scene back (every channel, and the trainer's four).

--compression also encodes the after side's frames with each lossless OpenEXR compression (size,
encode and decode CPU seconds: docs/results/exr_compression.md). Then it prints both sides side by
side, with the core-seconds per scene of this run and the 15,000- and 1,000,000-scene plans
(docs/SCALE.md) recomputed from them. Medians of --repeats.
Run it on idle cores: the children run one after another and each uses every core.
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
import tomllib
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
FULL_WIDTH = 1216
TRAIN_CHANNELS = ("ir", "visibility", "edge", "projector_column")  # trainer/samples.py's
# Stage rows: (label, function, caller or None). With a caller, the time of that call edge (the
# stages make_frame calls); without, the function's own total (the writer's stages). A function
# renamed since is "old|new": whichever the side's code has.
STAGES = (
    ("checks, depth, flood", "make_frame", None),
    ("exposure (auto gain)", "exposure_gain", "make_frame"),
    ("sensor model (IR)", "apply_sensor_model|apply", "make_frame"),
    ("visibility mask", "direct_visibility_mask", "make_frame"),
    ("edge mask", "edge_mask", "make_frame"),
    ("ground truth: projector column", "depth_to_projector_column", "make_frame"),
    ("ground truth: disparity", "depth_to_disparity", "make_frame"),
    ("frame checks and dtypes", "_frame_pixels", None),
    ("EXR encoding", "encode_frame", None),
    ("hashing (sha256)", "sha256_bytes", None),
    ("writing files (fsync, rename)", "atomic_write_bytes", None),
    ("other writing (scene.json, folders)", "write_scene", None),
)


def median_run(function, repeats: int) -> tuple[float, float]:
    """Median wall and CPU (this process, all its threads) seconds of function()."""
    walls, cpus = [], []
    for _ in range(repeats):
        wall, cpu = time.perf_counter(), time.process_time()
        function()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    return statistics.median(walls), statistics.median(cpus)


def stage_seconds(profile: cProfile.Profile) -> dict[str, float]:
    """Seconds per stage of STAGES from a profile of make_frame and write_scene calls; the first
    row and the last are what their function spent outside the other rows."""
    stats = pstats.Stats(profile).stats
    by_name = {}
    for (_, _, name), entry in stats.items():
        by_name.setdefault(name, []).append(entry)

    def total(name):  # cumulative seconds of every function of that name
        return sum(entry[3] for entry in by_name.get(name, []))

    def edge(name, caller):
        return sum(ct for entry in by_name.get(name, []) for (_, _, c), (_, _, _, ct) in entry[4].items()
                   if c == caller)

    out = {}
    for label, names, caller in STAGES:
        for name in names.split("|"):
            if name in by_name:  # a stage the side's code does not have is left out
                out[label] = edge(name, caller) if caller else total(name)
                break
    out["checks, depth, flood"] -= sum(out.get(label, 0.0) for label, _, caller in STAGES if caller)
    out["EXR encoding"] -= out["frame checks and dtypes"]
    out["other writing (scene.json, folders)"] -= sum(
        total(name) for name in ("encode_frame", "sha256_bytes", "atomic_write_bytes"))
    return out


COMPRESSIONS = ("ZIP_COMPRESSION", "ZIPS_COMPRESSION", "PIZ_COMPRESSION", "ZSTD_COMPRESSION",
                "HTJ2K32_COMPRESSION")


def compression_table(frames: list[dict], meta: dict, repeats: int) -> dict[str, tuple[float, float, float]]:
    """Each lossless OpenEXR compression on the frames of one scene as format 2 stores them:
    {name: (MB per scene, encode seconds per frame, decode seconds per frame)}, CPU seconds."""
    from dotsim import dataset

    shape = (meta["rig"]["camera"]["height"], meta["rig"]["camera"]["width"])
    out = {}
    for name in COMPRESSIONS:
        def encode(name=name):
            return [dataset.encode_frame(f, shape, compression=name, rig=meta["rig"]) for f in frames]

        files = encode()
        encode_s = median_run(encode, repeats)[1]
        decode_s = median_run(lambda files=files: [dataset.decode_frame(d, Path("frame.exr")) for d in files],
                              repeats)[1]
        out[name] = (sum(map(len, files)) / 1e6, encode_s / len(frames), decode_s / len(frames))
    return out


def prepared(config, folder: Path):
    """The RenderJob of a train-split dataset in `folder` (seed 0), with either side's code."""
    try:
        from generator.engines.steps import prepare_run
    except ImportError:
        try:  # before issue 40, generator.run_steps held it
            from generator.run_steps import prepare_run
        except ImportError:  # before issue 37, generator.pipeline did
            from generator.pipeline import prepare_run
    try:
        from generator.run_request import RunRequest
    except ImportError:  # before issue 28, prepare_run took the run's values themselves
        return prepare_run(config, folder, "train", 0)
    return prepare_run(RunRequest(config, folder, "train", 1))


def measure(config_path: Path, width: int, scene: int, repeats: int, compressions: bool = False) -> dict:
    """The child's work: one side's code (on sys.path) at one width; a dict of seconds per frame."""
    from dotsim import dataset
    from generator import sample_scene
    from generator.blender.render import SceneRenderer
    from generator.config import config_from_dict
    from generator.post_render import make_frame
    try:
        from generator.render_worker import _finish_scene
    except ImportError:  # before issue 40, generator.render_scenes held it
        from generator.render_scenes import _finish_scene
    from generator.sample_scene import sample_scene_spec

    data = tomllib.loads(config_path.read_text())
    data["rig"]["scale"] = width / FULL_WIDTH
    data["assets"] = {"source": "primitives"}
    config = config_from_dict(data, source=f"{config_path} at {width} px", base_dir=config_path.parent)
    with tempfile.TemporaryDirectory(prefix="dotsim-stages-") as tmp:
        job = prepared(config, Path(tmp) / "d")
        spec = sample_scene_spec(config, scene, 0, "train", job.resources)
        frames = len(spec.poses)
        out = {"objects": len(spec.objects), "lights": len(spec.lights), "frames": frames,
               "cores": os.cpu_count()}
        out["sample SceneSpec"] = median_run(
            lambda: sample_scene_spec(config, scene, 0, "train", job.resources), repeats)[0] / frames
        renderer = SceneRenderer()
        raws = []
        wall, cpu = median_run(lambda: raws.append(renderer.render(spec)), repeats)
        out["render"] = (wall / frames, cpu / frames)
        raw_frames = raws[-1]
        renderer.close()

        scene_path = dataset.scene_dir(job.out, scene, config.output.scenes_per_shard)

        def finish():
            dataset.remove_scene(job.out, scene, config.output.scenes_per_shard)
            _finish_scene(job, spec, raw_frames)

        wall, cpu = median_run(finish, repeats)
        out["all-in work"] = (wall / frames, cpu / frames)
        out["MB per scene"] = sum(p.stat().st_size for p in scene_path.iterdir()) / 1e6
        out["read, every channel"] = median_run(lambda: dataset.read_scene(scene_path), repeats)[0] / frames
        out["read, the trainer's channels"] = median_run(
            lambda: dataset.read_scene(scene_path, channels=TRAIN_CHANNELS), repeats)[0] / frames

        # Stages, one frame after another in this thread (so cProfile sees them all).
        meta = json.loads((scene_path / dataset.SCENE_FILE).read_text())
        meta = {key: meta[key] for key in ("split", "rig", "pattern", "poses")}
        profile = cProfile.Profile(time.perf_counter)
        single = {"threads": 1} if "threads" in dataset.write_scene.__code__.co_varnames else {}

        def streams(i: int):
            """Frame i's random streams; a before side older than frame_streams takes its noise alone."""
            if hasattr(sample_scene, "frame_streams"):
                return sample_scene.frame_streams(0, spec, i)
            return sample_scene.frame_sensor_rng(0, scene, i)

        for k in range(repeats):
            profile.enable()
            made = [make_frame(raw, spec, streams(i)) for i, raw in enumerate(raw_frames)]
            dataset.write_scene(job.out, 1000 + k, meta, made, **single)
            profile.disable()
        out["stages"] = {label: seconds / repeats / frames
                         for label, seconds in stage_seconds(profile).items()}
        if compressions:
            out["compressions"] = compression_table(made, meta, repeats)
    return out


def unpack(revision: str, into: Path) -> Path:
    """The files of `revision` of this repository, unpacked into `into` (git archive)."""
    archive = into / "tree.tar"
    subprocess.run(["git", "-C", str(REPO), "archive", "-o", str(archive), revision], check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(into / "tree", filter="data")
    return into / "tree"


def dotsim_command(tree: Path) -> list[str]:
    """The `dotsim` program of checkout `tree`, run by this interpreter (PYTHONPATH=tree): its entry
    module is commands.cli, dotsim.cli in revisions before the commands had a folder of their own."""
    module = "commands.cli" if (tree / "commands" / "cli.py").is_file() else "dotsim.cli"
    return [sys.executable, "-m", module]


def run_side(tree: Path, config_path: Path, width: int, scene: int, repeats: int,
             compressions: bool = False) -> dict:
    """measure() in a child process whose imports come from `tree`."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    command = [sys.executable, str(Path(__file__).resolve()), "--child", str(config_path), str(width),
               str(scene), str(repeats), str(int(compressions))]
    done = subprocess.run(command, cwd=tree, env=env, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"the child for {tree} at {width} px failed:\n{done.stderr[-4000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def plan_rows(side: dict) -> dict[str, str]:
    """docs/SCALE.md's plans from this run: core-seconds and MB per full-size scene."""
    core_s = side["frames"] * (side["render"][1] + side["all-in work"][1])
    mb = side["MB per scene"]
    rows = {"core-seconds per scene (render + work, CPU)": f"{core_s:.1f}",
            "scenes per 32-core node-hour": f"{32 * 3600 / core_s:,.0f}"}
    for scenes in (15_000, 1_000_000):
        rows[f"{scenes:,} scenes: core-hours"] = f"{scenes * core_s / 3600:,.0f}"
        rows[f"{scenes:,} scenes: storage"] = f"{scenes * mb / 1e6:,.2f} TB"
    rows["1,000,000 scenes on 1,000 nodes x 32 cores: wall"] = f"{1e6 * core_s / 32_000 / 60:,.0f} min"
    return rows


def print_table(results: dict, before: str) -> None:
    sides = ("before", "after")
    for width, by_side in results.items():
        first = by_side["after"]
        print(f"\n{width} x {round(width * 896 / FULL_WIDTH)}: scene with {first['objects']} objects, "
              f"{first['lights']} extra lights, {first['frames']} frames, {first['cores']} cores; "
              f"seconds per frame (before = {before}, after = this checkout)")
        print(f"{'':44}{'before':>10}{'after':>10}")

        def row(label, values, fmt="{:>10.3f}"):
            print(f"{label:44}" + "".join(fmt.format(v) if v is not None else f"{'-':>10}" for v in values))

        row("render, wall", [by_side[s]["render"][0] for s in sides])
        row("render, CPU (all threads)", [by_side[s]["render"][1] for s in sides])
        row("sample SceneSpec (per frame)", [by_side[s]["sample SceneSpec"] for s in sides])
        labels = [label for label, _, _ in STAGES]
        for label in labels:
            row(f"  {label}", [by_side[s]["stages"].get(label) for s in sides])
        row("  sum of the stages, one thread", [sum(by_side[s]["stages"].values()) for s in sides])
        row("all-in work, wall (the generator's path)", [by_side[s]["all-in work"][0] for s in sides])
        row("all-in work, CPU", [by_side[s]["all-in work"][1] for s in sides])
        row("all-in work / render, wall", [by_side[s]["all-in work"][0] / by_side[s]["render"][0]
                                           for s in sides], "{:>10.1%}")
        row("all-in work / render, CPU", [by_side[s]["all-in work"][1] / by_side[s]["render"][1]
                                          for s in sides], "{:>10.1%}")
        row("all-in per frame, wall (render + work)",
            [by_side[s]["render"][0] + by_side[s]["all-in work"][0] for s in sides])
        row("MB per scene", [by_side[s]["MB per scene"] for s in sides], "{:>10.1f}")
        row("read, every channel", [by_side[s]["read, every channel"] for s in sides])
        row("read, the trainer's channels", [by_side[s]["read, the trainer's channels"] for s in sides])
        if "compressions" in by_side["after"]:
            print("lossless compressions on the after side's frames (format 2 channels; CPU s per frame):")
            print(f"  {'compression':20}{'MB/scene':>10}{'encode':>10}{'decode':>10}")
            for name, (mb, encode, decode) in by_side["after"]["compressions"].items():
                print(f"  {name.removesuffix('_COMPRESSION'):20}{mb:>10.1f}{encode:>10.3f}{decode:>10.3f}")
        if width == FULL_WIDTH:
            plans = {s: plan_rows(by_side[s]) for s in sides}
            print("plans at full size from this run (docs/SCALE.md):")
            for label in plans["after"]:
                print(f"  {label:42}" + "".join(f"{plans[s][label]:>12}" for s in sides))


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        width, scene, repeats, compressions = map(int, argv[2:6])
        print(json.dumps(measure(Path(argv[1]), width, scene, repeats, bool(compressions))))
        return 0
    parser = argparse.ArgumentParser(prog="python -m bench.generate_stages",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="608,1216", help="IR widths, comma-separated (default 608,1216)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scene", type=int, default=0, help="scene index (default 0: has extra lights)")
    parser.add_argument("--before", default="7369d4c", help="git revision measured as `before` "
                        "(default 7369d4c, main before issue 26)")
    parser.add_argument("--compression", action="store_true",
                        help="also encode the after side's frames with each lossless OpenEXR compression")
    args = parser.parse_args(argv)
    started = time.perf_counter()
    results = {}
    with tempfile.TemporaryDirectory(prefix="dotsim-before-") as tmp:
        trees = {"before": unpack(args.before, Path(tmp)), "after": REPO}
        # Both sides render the before side's config, so they render the same scene whatever the
        # configs have become since (they moved to dotsim/configs/ and changed their layout).
        config_path = next(path for path in (trees["before"] / "dotsim" / "configs" / "structure_core.toml",
                                             trees["before"] / "configs" / "structure_core.toml")
                           if path.is_file())
        for width in (int(w) for w in args.sizes.split(",")):
            results[width] = {side: run_side(tree, config_path, width, args.scene, args.repeats,
                                             args.compression and side == "after")
                              for side, tree in trees.items()}
    print_table(results, args.before)
    print(f"\n(one run, {time.perf_counter() - started:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
