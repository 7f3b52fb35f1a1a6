"""The add-on as a Blender extension: build the zip (blender_addon/build_extension.py), install it
with bpy's own extension operators in a Python that sees only bpy and what Blender bundles, render a
preview through the panel and compare it with the frame `dotsim generate` writes.

The zip is built offline from this venv's installed packages (--from-venv: the same versions a PyPI
build pins). The Blender session runs in a subprocess started with `python -S`: no site-packages,
only symlinks to bpy and its own requirements (numpy, Cython, requests, zstandard: what the Blender
application bundles), with Blender's user folders in a temporary directory. So dotsim, OpenCV,
scipy, ... can only come from the extension's wheels, and nothing is left in the home folder.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import re
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import numpy as np
import pytest

from blender_addon.build_extension import (
    PREVIEW_DISTRIBUTIONS,
    ExtensionBuildError,
    build_extension,
    download_wheels,
    main,
    pinned_requirements,
    this_platform,
)
from dotsim.version import __version__
from tests.blender_addon.generated_scene import BASE_SEED, CONFIG, SCENE_INDEX, SPLIT

pytest.importorskip("bpy")

REPO = Path(__file__).resolve().parents[2]
SESSION = Path(__file__).with_name("blender_extension_session.py")  # run in its own Python
FRAME = 2
KALIBR_CAMCHAIN = """cam0:
  camera_model: pinhole
  intrinsics: [600.0, 600.0, 319.5, 239.5]
  distortion_model: radtan
  distortion_coeffs: [-0.1, 0.02, 0.0, 0.0]
  resolution: [640, 480]
  rostopic: /ir/image_raw
cam1:
  T_cn_cnm1:
  - [1.0, 0.0, 0.0, -0.05]
  - [0.0, 1.0, 0.0, 0.0]
  - [0.0, 0.0, 1.0, 0.0]
  - [0.0, 0.0, 0.0, 1.0]
  camera_model: pinhole
  intrinsics: [1200.0, 1200.0, 799.5, 599.5]
  distortion_model: radtan
  distortion_coeffs: [0.0, 0.0, 0.0, 0.0]
  resolution: [1600, 1200]
"""


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("extension")
    (path,) = build_extension(folder / "dist", [this_platform()], from_venv=True, staging=folder / "staging")
    return path


def _distribution_key(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def blender_bundle(folder: Path) -> Path:
    """`folder` holding symlinks to bpy and its requirements, recursively: what the Blender
    application ships beside its Python (numpy among them)."""
    folder.mkdir()
    todo, seen = ["bpy"], set()
    while todo:
        name = todo.pop()
        if _distribution_key(name) in seen:
            continue
        seen.add(_distribution_key(name))
        dist = importlib.metadata.distribution(name)
        todo += [re.split(r"[ ;<>=!~\[(]", requirement, maxsplit=1)[0]
                 for requirement in dist.requires or [] if "extra ==" not in requirement]
        for top in {str(f).split("/")[0] for f in dist.files} - {"..", "__pycache__"}:
            if not (folder / top).exists():
                os.symlink(dist.locate_file(top), folder / top)
    return folder


@pytest.fixture(scope="module")
def session(tmp_path_factory, extension_zip, dataset_scene):
    """What the Blender session with the installed extension saw (blender_extension_session.py)."""
    tmp = tmp_path_factory.mktemp("extension_session")
    bad_toml = tmp / "unreadable.toml"
    bad_toml.write_bytes(b"\xff\xfe[rig]\x00 scale = ")
    no_cache = tmp / "no_cache.toml"
    no_cache.write_text(CONFIG.read_text() + '\n[assets]\nsource = "cache"\ncache_dir = "no_such_cache"\n')
    kalibr = tmp / "camchain.yaml"  # plain YAML, as Kalibr writes it: read with the bundled PyYAML
    kalibr.write_text(KALIBR_CAMCHAIN)
    params = {"zip": str(extension_zip), "config": CONFIG.stem, "rig_file": str(kalibr), "split": SPLIT,
              "scene": SCENE_INDEX, "seed": BASE_SEED, "frame": FRAME, "work_dir": str(dataset_scene[0]),
              "bad_configs": {"unreadable": str(bad_toml), "missing_cache": str(no_cache)},
              "out": str(tmp / "seen.json"), "images": str(tmp / "images.npz")}
    (tmp / "params.json").write_text(json.dumps(params))
    bundle = blender_bundle(tmp / "blender_python")
    resources = tmp / "blender_user"
    env = {key: value for key, value in os.environ.items() if not key.startswith(("PYTHON", "BLENDER_"))}
    env.update(PYTHONPATH=str(bundle), HOME=str(tmp / "home"), BLENDER_USER_RESOURCES=str(resources))
    result = subprocess.run([sys.executable, "-S", "-P", str(SESSION),
                             str(tmp / "params.json")], cwd=tmp, env=env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    seen = json.loads((tmp / "seen.json").read_text())
    seen["console"] = result.stdout + result.stderr
    with np.load(tmp / "images.npz") as images:
        seen["images"] = dict(images)
    seen["bundle"], seen["resources"] = str(bundle), str(resources)
    return seen


def test_manifest_names_version_platform_and_every_wheel(extension_zip):
    assert extension_zip.name == f"dotsim-{__version__}-{this_platform().replace('-', '_')}.zip"
    with zipfile.ZipFile(extension_zip) as archive:
        names = set(archive.namelist())
        manifest = tomllib.loads(archive.read("blender_manifest.toml").decode())
    assert manifest["id"] == "dotsim" and manifest["type"] == "add-on"
    assert manifest["version"] == __version__
    assert manifest["blender_version_min"] == "4.2.0"
    assert manifest["license"] == ["SPDX:MIT"] and "files" in manifest["permissions"]
    assert manifest["platforms"] == manifest["build"]["generated"]["platforms"] == [this_platform()]
    wheels = {w.removeprefix("./") for w in manifest["wheels"]}
    assert wheels == {n for n in names if n.endswith(".whl")}
    wheel_keys = {_distribution_key(Path(w).name.split("-")[0]) for w in wheels}
    assert wheel_keys == {"dotsim", *map(_distribution_key, PREVIEW_DISTRIBUTIONS)}
    # setuptools read the version from dotsim/version.py (pyproject.toml's dynamic version)
    assert any(Path(w).name.startswith(f"dotsim-{__version__}-") for w in wheels)
    assert "numpy" not in wheel_keys  # Blender bundles it
    # The add-on's modules sit at the top; the build script and template stay out.
    addon = {p.name for p in (REPO / "blender_addon").glob("*.py")} - {"build_extension.py"}
    assert addon <= names and "__init__.py" in addon
    assert not {"build_extension.py", "blender_manifest.template.toml"} & names


def test_installed_extension_imports_only_its_wheels_and_what_blender_bundles(session):
    assert session["install"] == ["FINISHED"] and session["enabled"]
    site_packages = Path(session["site_packages"])
    assert site_packages.is_relative_to(session["resources"])
    outside = {name: path for name, path in session["imported_files"].items()
               if not any(Path(path).is_relative_to(session[where]) for where in ("resources", "bundle"))}
    assert not outside, f"imported from neither the extension nor Blender's bundle: {outside}"
    for module in ("dotsim", "generator", "cv2", "scipy"):
        assert Path(session["imported_files"][module]).is_relative_to(site_packages)
    # Small: every wheel it bundles was imported by the preview.
    for distribution, tops in session["bundled"].items():
        modules = {t.split(".")[0] for t in tops if not t.endswith((".dist-info", ".libs"))}
        assert modules & set(session["imported_files"]), f"{distribution} is bundled but never imported"


def test_preview_through_installed_extension_is_the_dataset_frame(session, dataset_scene):
    # no checkout: the built-in config comes from the extension's own dotsim, nothing from this repo
    assert Path(session["builtin_configs"]).is_relative_to(session["site_packages"])
    # (Blender's own Python, the bpy wheel, may lie in a virtual environment inside the checkout, as
    # `make test` makes it: only the checkout's sources count)
    venv = Path(sys.prefix).resolve()
    assert not [p for p in session["sys_path"] if p and Path(p).resolve().is_relative_to(REPO)
                and not Path(p).resolve().is_relative_to(venv)]
    assert "tiny" in session["config_choices"] and "train_tiny" not in session["config_choices"]
    assert session["config_choices"][-1] == "FILE"
    assert session["rig_choices"] == ["CONFIG", "ctd_synthetic", "kinect_v1", "realsense_d415",
                                      "realsense_d435", "structure_core", "FILE"]
    assert session["build_scene"]["result"] == ["FINISHED"], session["build_scene"]
    assert session["preview_frame"]["result"] == ["FINISHED"], session["preview_frame"]
    assert f"frame {FRAME} of scene {SCENE_INDEX}" in session["preview_frame"]["status"]
    frame = dataset_scene[2][FRAME]
    ir, depth = session["images"]["ir"], session["images"]["depth"]
    assert ir.shape == frame["ir"].shape and ir.std() > 0.01
    # Equal up to the dataset's float16 storage of IR (half a step near 0.5 is 2.4e-4).
    np.testing.assert_allclose(ir, frame["ir"].astype(np.float32), atol=2.5e-4)
    hit = np.isfinite(frame["depth"])
    assert hit.mean() > 0.5
    np.testing.assert_allclose(depth[hit], frame["depth"][hit], rtol=1e-6)
    assert np.all(depth[~hit] == 0)


def test_rig_file_through_installed_extension(session):
    """A Kalibr camchain chosen as the rig file: the spec renders its pinhole rig at tiny's scale."""
    assert session["rig_file"]["result"] == ["FINISHED"], session["rig_file"]
    rig = session["rig_file"]["rig"]
    assert rig["camera"] == {"width": 64, "height": 48, "fx": 60.0, "fy": 60.0, "cx": 31.5, "cy": 23.5}
    assert rig["projector_translation"] == [0.05, 0.0, 0.0] and rig["projector"]["width"] == 160


@pytest.mark.parametrize("case, expected", [
    ("unreadable", r"unreadable\.toml: not valid TOML"),
    ("missing_cache", r"no_cache\.toml: \[assets\] cache_dir = '[^']*/no_such_cache': directory not found"),
])
def test_bad_config_is_an_error_report_not_a_traceback(session, case, expected):
    for operator, outcome in session["bad_input"][case].items():
        # Blender raises an ERROR report as RuntimeError("Error: <message>") for Python callers;
        # an uncaught exception would read "Error: Python: Traceback ...".
        assert re.match(rf"Error: .*{expected}", outcome.get("error", "")), (operator, outcome)
        assert "Traceback" not in outcome["error"]
        assert re.match(rf"error: .*{expected}", outcome["status"])
    assert re.search(rf"dotsim: error: .*{expected}", session["console"])


def test_uninstall_removes_the_extension_and_its_wheels(session):
    assert session["uninstall"] == ["FINISHED"]
    assert not session["enabled_after_uninstall"]
    assert not session["extension_dir_after_uninstall"]
    left = session["left_after_uninstall"]
    assert not [name for name in left if name.startswith(("dotsim", "generator", "cv2"))], left


def test_command_line_installs_and_removes_it(session):
    assert session["command_line"] == {"install_file": 0, "enabled_after_install": True, "remove": 0,
                                       "enabled_after_remove": False}


def test_unknown_platform_or_foreign_venv_build_is_refused(tmp_path, capsys):
    with pytest.raises(ExtensionBuildError, match="platform beos-x64: allowed: linux-x64"):
        build_extension(tmp_path, ["beos-x64"])
    other = "windows-x64" if this_platform() != "windows-x64" else "linux-x64"
    assert main(["--from-venv", "--platform", other, "--out", str(tmp_path)]) == 1
    assert f"--from-venv builds only this machine's platform ({this_platform()})" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("python_platform, blender_platform", [
    ("linux-x86_64", "linux-x64"), ("linux-aarch64", "linux-arm64"), ("macosx-11.0-arm64", "macos-arm64"),
    ("macosx-10.9-x86_64", "macos-x64"), ("win-amd64", "windows-x64"), ("win-arm64", "windows-arm64"),
])
def test_this_platform_in_blenders_spelling(monkeypatch, python_platform, blender_platform):
    monkeypatch.setattr("sysconfig.get_platform", lambda: python_platform)
    assert this_platform() == blender_platform


def test_cached_wheels_are_not_downloaded_again(tmp_path, monkeypatch):
    requirements = pinned_requirements()
    folder = tmp_path / "macos-arm64"
    folder.mkdir()
    expected = []
    for requirement in requirements:
        name, _, version = requirement.partition("==")
        wheel = folder / f"{re.sub(r'[-_.]+', '_', name)}-{version}-cp311-cp311-macosx_11_0_arm64.whl"
        wheel.write_bytes(b"")
        expected.append(wheel)
    (folder / "scipy-0.1-cp311-cp311-macosx_11_0_arm64.whl").write_bytes(b"")  # another version

    def no_pip(*args, **kwargs):
        raise AssertionError(f"pip ran: {args}")

    monkeypatch.setattr("subprocess.run", no_pip)
    assert download_wheels(requirements, "macos-arm64", tmp_path) == expected
