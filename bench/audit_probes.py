"""Issue 45's audit, replayable: every input that once lost data or failed without a clear word, run
again against the commands, each probe printing whether the fix held.

    python -m bench.audit_probes --work /tmp/audit            # everything (renders one tiny scene)
    python -m bench.audit_probes --only config folders        # the groups that need no render
    python -m bench.audit_probes --list

Groups (--only):
- config: settings that contradict each other, refused at load in one line naming them: [model]
  stride 0 / -1 / 100, min_depth just below max_depth, a zero-baseline rig file, a back wall nearer
  than the objects; a config's max_depth left out is its preset's, and a refusal of another rig's data
  names both values.
- folders: every writing command (generate, capture import, export, train, eval, infer) into a folder
  of each other kind and into one of a user's own files: refused in one line naming what is there, the
  folder byte for byte as it was, `dotsim verify` of a dataset still clean.
- data: the listed failures on real data: view and eval of a capture (no depth), eval of an export
  of the IR alone, stats of and training on frames with nothing visible, export --shards beyond the
  samples, view --predictions of another input, a train that fails before its first checkpoint (no
  RUN/tb).

Inputs are made here with the commands themselves at tiny sizes: a captured dataset from random
122 x 90 PNG pairs, a rendered one by `dotsim generate --config tiny` (one scene of four frames; the
data and folders groups), a one-step training run on it, its export, eval and infer folders. Prints
one line per probe (held / FAILED and what was seen) and the counts; exit status 1 when any failed.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import shutil
import sys
import tempfile
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np

from commands.cli import main as dotsim

GROUPS = ("config", "folders", "data")
CAMERA = (90, 122)  # structure_core at scale 0.1 (the tiny config's camera), rows x columns


def run(*argv) -> tuple[int, str, str]:
    """`dotsim ARGV` in this process: (exit status, stdout, stderr)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            status = dotsim([str(a) for a in argv])
        except SystemExit as exit_:
            status = exit_.code if isinstance(exit_.code, int) else 2
    return status, out.getvalue(), err.getvalue()


def one_line(err: str, *names: str) -> bool:
    """stderr is one error line, no traceback, naming every one of `names`."""
    lines = [line for line in err.split("\n") if line and "\r" not in line]
    return len(lines) == 1 and "Traceback" not in err and ": error: " in lines[0] and all(
        n in lines[0] for n in names)


def snapshot(root: Path) -> dict[str, bytes | None]:
    return {str(p.relative_to(root)): None if p.is_dir() else p.read_bytes() for p in sorted(root.rglob("*"))}


class Inputs:
    """The inputs of the probes, each made once, when a probe first asks for it."""

    def __init__(self, work: Path):
        self.work = work
        self._made: dict[str, Path] = {}

    def __getattr__(self, name: str) -> Path:
        if name.startswith("_"):
            raise AttributeError(name)
        if name not in self._made:
            self._made[name] = getattr(self, f"_make_{name}")()
        return self._made[name]

    def _check(self, status: int, what: str, err: str = "") -> None:
        if status != 0:
            raise RuntimeError(f"making the input {what} failed: {err.strip()[-300:]}")

    def _make_frames(self) -> Path:
        import cv2

        rng = np.random.default_rng(0)
        for name in ("on", "off"):
            (self.work / name).mkdir(parents=True, exist_ok=True)
            for k in range(2):
                image = rng.integers(0, 256, CAMERA, dtype=np.uint8)
                cv2.imwrite(str(self.work / name / f"f_{k}.png"), image)
        return self.work

    def _make_captured(self) -> Path:
        out = self.work / "captured"
        status, _, err = run("capture", "import", "--on", self.frames / "on", "--off", self.frames / "off",
                             "--scale", "0.1", "--frames-per-scene", "2", "--out", out, "--no-progress")
        self._check(status, "captured", err)
        return out

    def _make_rendered(self) -> Path:
        out = self.work / "rendered"
        status, _, err = run("generate", "--config", "tiny", "--out", out, "--split", "test", "--scenes", "1",
                             "--no-progress")
        self._check(status, "rendered", err)
        return out

    def _make_run(self) -> Path:
        out = self.work / "run"
        status, _, err = run("train", "--config", "train_tiny", "--data", self.rendered, "--split", "all",
                             "--out", out, "--max-steps", "1", "--no-progress")
        self._check(status, "run", err)
        return out

    def _make_export(self) -> Path:
        status, _, err = run("export", self.rendered, "-o", self.work / "export")
        self._check(status, "export", err)
        return self.work / "export"

    def _make_export_ir(self) -> Path:
        status, _, err = run("export", self.rendered, "-o", self.work / "export_ir", "--channels", "ir")
        self._check(status, "export_ir", err)
        return self.work / "export_ir"

    def _make_eval(self) -> Path:
        status, _, err = run("eval", "--checkpoint", self.run / "checkpoint.pt", "--data", self.rendered,
                             "--split", "all", "--images", "1", "--out", self.work / "eval", "--no-progress")
        self._check(status, "eval", err)
        return self.work / "eval"

    def _make_predictions(self) -> Path:
        status, _, err = run("infer", "--checkpoint", self.run / "checkpoint.pt", self.frame,
                             "--out", self.work / "predictions", "--no-progress")
        self._check(status, "predictions", err)
        return self.work / "predictions"

    def _make_frame(self) -> Path:
        return next(self.rendered.glob("shard_*/scene_*/frame_0.exr"))

    def _make_notes(self) -> Path:
        (self.work / "notes").mkdir(parents=True, exist_ok=True)
        (self.work / "notes" / "notes.txt").write_text("my own notes")
        (self.work / "notes" / "shard-000000.tar").write_bytes(b"not dotsim's")
        return self.work / "notes"


# ----------------------------------------------------------------------------- config


def _config_error(load: Callable[[], object], *names: str) -> tuple[bool, str]:
    from dotsim.config_schema import ConfigError

    try:
        load()
    except ConfigError as error:
        text = str(error)
        return all(n in text for n in names) and "\n" not in text, text
    return False, "accepted"


def config_probes(inputs: Inputs) -> dict[str, Callable[[], tuple[bool, str]]]:
    from dotsim.rig.files import rig_file_json
    from dotsim.rig.presets import get_preset
    from generator.config import config_from_dict as generator_config
    from trainer.config import config_from_dict as trainer_config
    from trainer.config import load_config as load_trainer_config
    from trainer.model import feasible_positions

    train = load_trainer_config("train_tiny")
    probes = {}
    for stride in (0, -1, 100):
        data = train.to_dict()
        data["model"]["stride"] = stride
        probes[f"item 5: [model] stride = {stride}"] = lambda d=data, s=stride: _config_error(
            lambda: trainer_config(d, "probe.toml"), f"[model] stride = {s}", "one of 1, 2")
    rig = get_preset("structure_core").scaled(0.1)
    probes["item 5: [model] min_depth 19.9 m of a 20 m rig"] = lambda: _config_error(
        lambda: feasible_positions(replace(train.model, min_depth=19.9), rig), "min_depth = 19.9 m",
        "too close to the rig's max_depth 20 m", "at most")

    def zero_baseline():
        flat = inputs.work / "flat_rig.json"
        flat_rig = replace(get_preset("structure_core"), projector_translation=(0, 0, 0))
        flat.write_bytes(rig_file_json(flat_rig))
        return generator_config({"rig": {"file": str(flat)}}, "probe.toml")

    probes["item 9: a rig file of zero baseline"] = lambda: _config_error(
        zero_baseline, "probe.toml: [rig]", "baseline) is 0 m", "allowed: > 0")
    probes["item 9: [rig] baseline = -0.05"] = lambda: _config_error(
        lambda: generator_config({"rig": {"baseline": -0.05}}, "probe.toml"), "baseline) is -0.05 m")
    probes["item 10: back wall nearer than the objects"] = lambda: _config_error(
        lambda: generator_config({"scene": {"distance": [1.0, 3.0], "back_wall_distance": [0.5, 0.8],
                                            "room_size": [4.0, 6.0]}}, "probe.toml"),
        "[scene] back_wall_distance = [0.5, 0.8] is not beyond [scene] distance = [1.0, 3.0]")

    def preset_range():
        config = generator_config({"rig": {"preset": "realsense_d415"}}, "probe.toml")
        depth = config.calibrated_rig.rig.max_depth
        return depth == 10.0, f"max_depth left out: {depth:g} m"

    probes["max_depth: left out, the preset's own"] = preset_range

    def rig_message():
        from trainer.checkpoint import check_rig
        from trainer.samples import DataError

        try:
            check_rig(rig, replace(rig, max_depth=10.0), "checkpoint", "captured")
        except DataError as error:
            return "max_depth 10.0 here, 20.0 in the checkpoint" in str(error), str(error)
        return False, "accepted"

    probes["max_depth: another rig's refusal names both values"] = rig_message
    return probes


# ----------------------------------------------------------------------------- folders


# command -> (argv writing into OUT, the folders of its own kind)
def _writers(inputs: Inputs) -> dict[str, tuple[Callable[[Path], list], set[str]]]:
    return {
        "generate": (lambda out: ["generate", "--config", "tiny", "--out", out, "--split", "test",
                                  "--scenes", "1", "--no-progress"], {"rendered"}),
        "capture import": (lambda out: ["capture", "import", "--on", inputs.frames / "on", "--off",
                                        inputs.frames / "off", "--scale", "0.1", "--frames-per-scene", "2",
                                        "--out", out], {"captured"}),
        "export": (lambda out: ["export", inputs.rendered, "-o", out], {"export", "export_ir"}),
        "train": (lambda out: ["train", "--config", "train_tiny", "--data", inputs.rendered, "--split",
                               "all", "--out", out, "--max-steps", "1", "--no-progress"], {"run"}),
        "eval": (lambda out: ["eval", "--checkpoint", inputs.run / "checkpoint.pt", "--data", inputs.rendered,
                              "--split", "all", "--out", out, "--no-progress"], {"eval"}),
        "infer": (lambda out: ["infer", "--checkpoint", inputs.run / "checkpoint.pt", inputs.frame, "--out",
                               out, "--no-progress"], {"predictions"}),
    }


FOLDERS = ("rendered", "captured", "export", "run", "eval", "predictions", "notes")


def folder_probes(inputs: Inputs) -> dict[str, Callable[[], tuple[bool, str]]]:
    probes = {}
    for command, (argv, own) in _writers(inputs).items():
        for folder in FOLDERS:
            if folder in own:
                continue

            def probe(argv=argv, folder=folder, command=command):
                out = getattr(inputs, folder)
                before = snapshot(out)
                status, _, err = run(*argv(out))
                held = (status != 0 and one_line(err, str(out), "holds", f"dotsim {command} writes only into")
                        and snapshot(out) == before)
                if folder in ("rendered", "captured"):
                    held = held and run("verify", out)[0] == 0
                return held, err.strip().splitlines()[-1] if err.strip() else f"exit {status}"

            item = {"export": "item 1: ", "generate": "item 2: "}.get(command, "")
            probes[f"{item}{command} into {folder}"] = probe
    return probes


# ----------------------------------------------------------------------------- data


def data_probes(inputs: Inputs) -> dict[str, Callable[[], tuple[bool, str]]]:
    from dotsim import dataset as ds

    probes = {}

    def refused(*argv, names=()):
        status, _, err = run(*argv)
        seen = err.strip().splitlines()[-1] if err.strip() else "exit 0"
        return status != 0 and one_line(err, *names), seen

    def view_capture():
        try:
            import rerun  # noqa: F401
        except ImportError:
            return True, "skipped: rerun-sdk not installed"
        status, out, err = run("view", inputs.captured, "--save", inputs.work / "captured.rrd")
        return status == 0 and "Traceback" not in err, (out + err).strip().splitlines()[-1]

    probes["item 3: view a capture (no depth)"] = view_capture
    probes["item 14: eval a capture"] = lambda: refused(
        "eval", "--checkpoint", inputs.run / "checkpoint.pt", "--data", inputs.captured, "--split", "all",
        "--out", inputs.work / "eval_captured", "--no-progress", names=("nothing to score",))
    probes["item 15: eval an export of ir alone"] = lambda: refused(
        "eval", "--checkpoint", inputs.run / "checkpoint.pt", "--data", inputs.export_ir, "--split", "all",
        "--out", inputs.work / "eval_ir", "--no-progress",
        names=("its frames store ir, not", "nothing to score"))

    def dark_data() -> Path:
        """The rendered scene with its visibility zeroed: frames with nothing visible."""
        dark = inputs.work / "dark"
        if not dark.exists():
            scene = ds.open_dataset(inputs.rendered).scenes[0]
            meta = ds.read_scene_meta(scene.path)
            frames = [ds.read_frame(path, meta=meta) for path in scene.frame_paths]
            for frame in frames:
                frame["visibility"][:] = 0
            keep = {k: meta[k] for k in ("split", "rig", "pattern", "poses")}
            ds.write_scene(dark, 0, keep, [{k: v for k, v in f.items() if k not in ds.DERIVED_CHANNELS}
                                           for f in frames])
            ds.seal_dataset(dark)
        return dark

    def stats_dark():
        status, out, err = run("stats", dark_data(), "-o", inputs.work / "dark_stats.png")
        written = (inputs.work / "dark_stats.json").is_file()
        summary = json.loads((inputs.work / "dark_stats.json").read_text()) if written else {}
        held = status == 0 and written and "is visible" in err and summary["visible"]["median_m"] is None
        return held, err.strip().splitlines()[-1] if err.strip() else f"exit {status}"

    probes["item 4: stats of frames with nothing visible"] = stats_dark

    def train_dark():
        status, _, err = run("train", "--config", "train_tiny", "--data", dark_data(), "--split", "all",
                             "--out", inputs.work / "dark_run", "--max-steps", "1", "--no-progress")
        return status == 0 and "the loss was 0 at every one" in err, err.strip().splitlines()[-1]

    probes["training on frames with nothing visible says so"] = train_dark
    probes["item 16: export --shards beyond the samples"] = lambda: refused(
        "export", inputs.rendered, "-o", inputs.work / "export_99", "--shards", "99",
        names=("--shards 99", "allowed: 1 to 4"))

    def three_shards():
        status, _, err = run("export", inputs.rendered, "-o", inputs.work / "export_3", "--shards", "3")
        shards = sorted((inputs.work / "export_3").glob("shard-*.tar")) if status == 0 else []
        return len(shards) == 3, f"{len(shards)} shard(s) of --shards 3 over 4 samples"

    probes["item 16: export --shards 3 of 4 samples"] = three_shards

    def foreign_prediction():
        try:
            import rerun  # noqa: F401
        except ImportError:
            return True, "skipped: rerun-sdk not installed"
        from dotsim.prediction_file import write_prediction

        other = inputs.work / "elsewhere.exr"
        shutil.copyfile(inputs.frame, other)
        folder = inputs.work / "foreign_predictions"
        folder.mkdir(exist_ok=True)
        frame = ds.read_frame(inputs.frame)
        write_prediction(folder / f"{inputs.frame.parent.name}_frame_0.exr",
                         {"disparity": frame["disparity"], "depth": frame["depth"]},
                         {"checkpoint": "probe", "input": str(other), "precision": "float32"})
        return refused("view", inputs.frame.parent, "--frame", "0", "--predictions", folder, "--save",
                       inputs.work / "foreign.rrd", names=("predicted from",))

    probes["item 17: view --predictions of another input"] = foreign_prediction

    def failed_train():
        damaged = inputs.work / "damaged"
        if not damaged.exists():
            shutil.copytree(inputs.rendered, damaged)
            for frame in damaged.glob("shard_*/scene_*/frame_*.exr"):
                frame.write_bytes(frame.read_bytes() + b"damage")
        out = inputs.work / "failed_run"
        status, _, err = run("train", "--config", "train_tiny", "--data", damaged, "--split", "all", "--out",
                             out, "--max-steps", "1", "--no-progress")
        return status != 0 and one_line(err) and not out.exists(), (
            f"exit {status}, {out.name} {'left behind' if out.exists() else 'not left'}")

    probes["train failing before its first checkpoint leaves no RUN/tb"] = failed_train
    return probes


PROBES = {"config": config_probes, "folders": folder_probes, "data": data_probes}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--work", type=Path, default=None,
                        help="folder for the inputs (default: a temporary one, removed at the end)")
    parser.add_argument("--only", nargs="+", choices=GROUPS, default=list(GROUPS), help="groups to run")
    parser.add_argument("--list", action="store_true", help="list the probes and exit")
    args = parser.parse_args(argv)
    with contextlib.ExitStack() as stack:
        work = args.work or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="audit-")))
        work.mkdir(parents=True, exist_ok=True)
        inputs = Inputs(work)
        probes = {name: probe for group in args.only for name, probe in PROBES[group](inputs).items()}
        if args.list:
            print("\n".join(probes))
            return 0
        held = failed = 0
        for name, probe in probes.items():
            try:
                ok, seen = probe()
            except Exception as error:  # noqa: BLE001 - a probe that breaks is a failed probe, named
                ok, seen = False, f"{type(error).__name__}: {error}"
            held, failed = held + ok, failed + (not ok)
            print(f"{'held  ' if ok else 'FAILED'} {name}: {seen[:160]}", flush=True)
        print(f"{held} held, {failed} failed of {held + failed} probes ({', '.join(args.only)})")
        return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
