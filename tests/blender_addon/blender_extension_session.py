"""One Blender session with the dotsim extension installed from its zip, run by
tests/blender_addon/test_blender_extension.py in a Python that sees only bpy and what Blender bundles.

Usage: python -S -P blender_extension_session.py PARAMS.json. Installs the zip into the user
extension repository (the caller points BLENDER_USER_RESOURCES at a temporary folder), drives the
panel's operators, uninstalls the extension, installs and removes it once more with the
command-line handler, and writes what it saw to PARAMS["out"] (JSON) and the
preview images to PARAMS["images"] (npz). Checks are the caller's: this only records.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
import sys
from pathlib import Path

import bpy
import numpy as np

ADDON = "bl_ext.user_default.dotsim"


def _pixels(name: str) -> np.ndarray:
    """(H, W) red channel of an image datablock, row 0 = top."""
    image = bpy.data.images[name]
    width, height = image.size
    pixels = np.empty(width * height * 4, np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(height, width, 4)[::-1, :, 0].copy()


def _run(operator: str) -> dict:
    """Outcome of bpy.ops.dotsim.<operator>(): its result or the error Blender raised, and the status."""
    try:
        outcome = {"result": sorted(getattr(bpy.ops.dotsim, operator)())}
    except RuntimeError as error:  # an ERROR report (or an uncaught exception) raises for Python callers
        outcome = {"error": str(error)}
    outcome["status"] = bpy.context.window_manager.dotsim.status
    return outcome


def _imported_files() -> dict[str, str]:
    """File of each imported top-level module that is not part of Python itself nor this script
    (bl_ext, Blender's package of extensions, has no file)."""
    stdlib = os.path.realpath(sys.base_prefix)
    files = {}
    for name, module in list(sys.modules.items()):
        path = getattr(module, "__file__", None)
        if ("." not in name and not name.startswith("__") and path and os.path.isabs(path)
                and not os.path.realpath(path).startswith(stdlib)):
            files[name] = path
    return files


def main(params: dict) -> dict:
    seen: dict = {}
    zip_path = params["zip"]
    seen["install"] = sorted(bpy.ops.extensions.package_install_files(
        filepath=zip_path, repo="user_default", enable_on_install=True))
    seen["enabled"] = ADDON in bpy.context.preferences.addons
    settings = bpy.context.window_manager.dotsim
    seen["config_choices"] = [item.identifier for item in settings.bl_rna.properties["config"].enum_items]
    seen["rig_choices"] = [item.identifier for item in settings.bl_rna.properties["rig"].enum_items]
    settings.config = params["config"]  # a built-in config, shipped inside the extension
    settings.split, settings.scene_index = params["split"], params["scene"]
    settings.base_seed = params["seed"]
    settings.work_dir = params["work_dir"]
    settings.frame = params["frame"]
    seen["build_scene"] = _run("build_scene")
    seen["preview_frame"] = _run("preview_frame")
    depth = bpy.data.images["dotsim preview depth"]
    np.savez(params["images"], ir=_pixels("dotsim preview"),
             depth=_pixels("dotsim preview depth") * depth["depth_scale_m"])
    seen["bad_input"] = {}
    settings.config = "FILE"
    for case, config in params["bad_configs"].items():
        settings.config_path = config
        seen["bad_input"][case] = {op: _run(op) for op in ("build_scene", "preview_frame", "show_spec")}

    settings.config, settings.rig, settings.rig_path = params["config"], "FILE", params["rig_file"]
    seen["rig_file"] = _run("show_spec")
    seen["rig_file"]["rig"] = json.loads(bpy.data.texts["dotsim spec"].as_string())["rig"]

    import dotsim

    site_packages = Path(dotsim.__file__).parents[1]  # where Blender unpacked the extension's wheels
    seen["site_packages"] = str(site_packages)
    from dotsim.configs import BUILTIN_DIR

    seen["builtin_configs"] = str(BUILTIN_DIR)
    seen["sys_path"] = sys.path
    seen["imported_files"] = _imported_files()
    seen["bundled"] = {dist.metadata["Name"]: sorted({str(f).split("/")[0] for f in dist.files})
                       for dist in importlib.metadata.distributions(path=[str(site_packages)])}

    repos = [repo.module for repo in bpy.context.preferences.extensions.repos]
    seen["uninstall"] = sorted(bpy.ops.extensions.package_uninstall(
        repo_index=repos.index("user_default"), pkg_id="dotsim"))
    seen["enabled_after_uninstall"] = ADDON in bpy.context.preferences.addons
    seen["left_after_uninstall"] = sorted(p.name for p in site_packages.glob("*"))
    seen["extension_dir_after_uninstall"] = os.path.exists(
        bpy.utils.user_resource("EXTENSIONS", path="user_default/dotsim"))

    # The handler `blender --command extension ...` runs, with the arguments docs/ADDON.md gives.
    from bl_pkg.bl_extension_cli import cli_extension_handler

    seen["command_line"] = {
        "install_file": cli_extension_handler(["install-file", "-r", "user_default", "-e", zip_path]),
        "enabled_after_install": ADDON in bpy.context.preferences.addons,
        "remove": cli_extension_handler(["remove", "user_default.dotsim"]),
        "enabled_after_remove": ADDON in bpy.context.preferences.addons,
    }
    return seen


if __name__ == "__main__":
    parameters = json.loads(Path(sys.argv[1]).read_text())
    Path(parameters["out"]).write_text(json.dumps(main(parameters), indent=1))
