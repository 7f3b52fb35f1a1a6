"""Every command that writes a folder writes only a new or empty one or one of its own kind
(dotsim.output_folder, issue 45 item 1): into a folder of each other kind, made by the real commands,
or of a user's own files, it is refused in one line naming what is there, and nothing in the folder
changes (`dotsim verify` of a dataset still passes)."""

from __future__ import annotations

import pytest

from assets_manifest.cache import build_asset_cache
from assets_manifest.manifest import load_manifest
from commands.cli import main
from dotsim import output_folder as of
from dotsim.frame_source import open_source
from dotsim.oracle_dataset import make_dataset
from dotsim.rig.files import rig_file_json
from dotsim.rig.presets import get_preset
from dotsim.shards.writer import export_webdataset
from tests.capture_inputs import write_on_off_frames
from tests.output_folders import assert_one_line_error, snapshot
from tests.trainer_fixtures import tiny_config

RIG = get_preset("structure_core").scaled(0.1)  # camera 122 x 90: the captures' frames

MANIFEST = """
[split]
name = "train"
clutter_density = 1.0

[[meshes]]
name = "blob"
generator = "noise_displaced_sphere"
seeds = [0, 1]
params = { subdivisions = 1 }
scale = [0.05, 0.3]
license = "CC0-1.0"
"""


@pytest.fixture(scope="module")
def world(tmp_path_factory):
    """Inputs (a dataset, a checkpoint, capture frames, a video, a rig file, a manifest) and a folder of
    every kind, each made by the command that writes it."""
    from trainer.evaluate import evaluate
    from trainer.infer import infer
    from trainer.train import train

    root = tmp_path_factory.mktemp("kinds")
    data = make_dataset(root / "data", scenes=2, frames_per_scene=2, test_scenes=1)
    run = root / "run"
    train(tiny_config(1), open_source(data, "train"), run, progress=False)
    inputs = root / "inputs"
    inputs.mkdir()
    write_on_off_frames(inputs, (RIG.camera.height, RIG.camera.width), seed=3, video=inputs / "ir.avi")
    (inputs / "rig.json").write_bytes(rig_file_json(RIG))
    (inputs / "train.toml").write_text(MANIFEST)
    frame = next(data.glob("shard_*/scene_*/frame_0.exr"))
    folders = {"rendered dataset": data, "training run": run}
    folders["captured dataset"] = root / "captured"
    assert main(["capture", "import", "--on", str(inputs / "on"), "--off", str(inputs / "off"), "--rig",
                 str(inputs / "rig.json"), "--frames-per-scene", "2", "--out", str(root / "captured"),
                 "--no-progress"]) == 0
    folders["export"] = export_webdataset(data, root / "export").out
    evaluate(run / "checkpoint.pt", open_source(data, "test"), root / "eval", progress=False, images=1)
    folders["eval"] = root / "eval"
    infer(run / "checkpoint.pt", [frame], root / "predictions", progress=False)
    folders["predictions"] = root / "predictions"
    build_asset_cache(load_manifest(inputs / "train.toml"), root / "cache", workers=1, progress=False,
                      log=lambda line: None)
    folders["asset cache"] = root / "cache"
    (root / "mine").mkdir()
    (root / "mine" / "notes.txt").write_text("my own notes")
    (root / "mine" / "shard-000000.tar").write_bytes(b"not dotsim's")
    folders["other files"] = root / "mine"
    return {"data": data, "run": run, "inputs": inputs, "frame": frame, "folders": folders}


# The kind check_output_folder finds in each folder, and what its refusal says is there.
FOUND = {
    "rendered dataset": ((of.DATASET,), "a dotsim dataset of rendered scenes (dataset.json"),
    "captured dataset": ((of.DATASET,), "a dotsim dataset of captured scenes (dataset.json"),
    "export": ((of.EXPORT,), "a `dotsim export` folder (index.json"),
    "training run": ((of.TRAINING_RUN,), "a `dotsim train` run (checkpoint.pt, tb/)"),
    "eval": ((of.EVAL,), "a `dotsim eval` folder (errors/, eval.csv, eval.md)"),
    "predictions": ((of.PREDICTIONS,), "`dotsim infer` predictions (scene_0000000_frame_0.exr"),
    "asset cache": ((of.ASSET_CACHE,), "an asset cache (`dotsim assets build`) (train/)"),
    "other files": ((), "files of no dotsim command (notes.txt, shard-000000.tar)"),
}

# command -> (argv writing into OUT, the folder kinds it writes, its exit status for a refusal)
COMMANDS = {
    "generate": (lambda w, out: ["generate", "--config", "tiny", "--out", out, "--split", "train", "--scenes",
                                 "1", "--no-progress"], {"rendered dataset"}, 2),
    "capture import": (lambda w, out: ["capture", "import", "--on", w["inputs"] / "on", "--off",
                                       w["inputs"] / "off", "--rig", w["inputs"] / "rig.json",
                                       "--frames-per-scene", "2", "--out", out], {"captured dataset"}, 2),
    "capture record": (lambda w, out: ["capture", "record", "--device", f"opencv:{w['inputs'] / 'ir.avi'}",
                                       "--rig", w["inputs"] / "rig.json", "--out", out, "--scenes", "1",
                                       "--frames", "2", "--no-progress", "--no-preview"],
                       {"captured dataset"}, 2),
    "export": (lambda w, out: ["export", w["data"], "-o", out], {"export"}, 1),
    "train": (lambda w, out: ["train", "--config", "train_tiny", "--data", w["data"], "--out", out,
                              "--max-steps", "1", "--no-progress"], {"training run"}, 1),
    "eval": (lambda w, out: ["eval", "--checkpoint", w["run"] / "checkpoint.pt", "--data", w["data"],
                             "--out", out, "--no-progress"], {"eval"}, 1),
    "infer": (lambda w, out: ["infer", "--checkpoint", w["run"] / "checkpoint.pt", w["frame"], "--out", out,
                              "--no-progress"], {"predictions"}, 1),
    "assets build": (lambda w, out: ["assets", "build", "--split", "train", "--manifest",
                                     w["inputs"] / "train.toml", "--cache", out, "--workers", "1",
                                     "--no-progress"], {"asset cache"}, 1),
}


@pytest.mark.parametrize("folder", FOUND)
def test_each_kind_is_told_by_what_its_command_wrote(folder, world):
    contents = of.folder_contents(world["folders"][folder])
    kinds, text = FOUND[folder]
    assert tuple(contents.kinds) == kinds and text in contents.text()


@pytest.mark.parametrize("command", COMMANDS)
@pytest.mark.parametrize("folder", FOUND)
def test_a_foreign_folder_is_refused_in_one_line_and_left_as_it_was(command, folder, world, capsys):
    argv, own, status = COMMANDS[command]
    if folder in own:
        pytest.skip("its own kind (resumes are tested beside each command)")
    out = world["folders"][folder]
    before = snapshot(out)
    capsys.readouterr()
    assert main([str(a) for a in argv(world, out)]) == status
    assert_one_line_error(capsys.readouterr().err, out, f"holds {FOUND[folder][1]}",
                          f"dotsim {command} writes only into a new or empty folder or")
    assert snapshot(out) == before
    if "dataset" in folder:
        assert main(["verify", str(out)]) == 0


def test_an_empty_folder_and_one_of_dotsim_temporaries_are_new(tmp_path):
    (tmp_path / ".tmp-shard-000000.tar-123").write_bytes(b"half")
    assert of.folder_contents(tmp_path).empty
    assert of.check_output_folder(tmp_path, of.EXPORT, "-o", "dotsim export") == tmp_path


def test_a_folder_of_two_kinds_names_both(world, tmp_path):
    (tmp_path / "checkpoint.pt").write_bytes(b"")
    (tmp_path / "eval.md").write_text("")
    with pytest.raises(of.OutputFolderError, match="a `dotsim train` run .checkpoint.pt. and a `dotsim eval` "
                                                   "folder .eval.md."):
        of.check_output_folder(tmp_path, of.TRAINING_RUN, "--out", "dotsim train")


# folder -> (kind, contents) the command that made it writes again (a resume, a rerun)
OWN = {"rendered dataset": (of.DATASET, of.RENDERED), "captured dataset": (of.DATASET, of.CAPTURED),
       "export": (of.EXPORT, None), "training run": (of.TRAINING_RUN, None), "eval": (of.EVAL, None),
       "predictions": (of.PREDICTIONS, None), "asset cache": (of.ASSET_CACHE, None)}


@pytest.mark.parametrize("folder", OWN)
def test_a_folder_of_the_commands_own_kind_is_accepted(folder, world):
    kind, contents = OWN[folder]
    path = world["folders"][folder]
    assert of.check_output_folder(path, kind, "--out", "dotsim x", contents) == path


def test_what_a_run_and_a_slurm_dataset_hold_beside_their_markers_is_theirs(tmp_path):
    """A run with its eval/ beside (the Makefile's RUN/eval) resumes; a dataset's logs/ and slurm/ are
    its own."""
    run = tmp_path / "run"
    (run / "tb").mkdir(parents=True)
    (run / "checkpoint.pt").write_bytes(b"")
    (run / "eval").mkdir()
    assert of.check_output_folder(run, of.TRAINING_RUN, "--out", "dotsim train") == run
    data = tmp_path / "data"
    for name in ("logs", "slurm/20261128"):
        (data / name).mkdir(parents=True)
    (data / "generate.json").write_text("{}")
    assert of.folder_contents(data).kinds == {of.DATASET: ["generate.json", "logs/", "slurm/"]}
