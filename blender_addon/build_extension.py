"""Build the add-on as a Blender extension: dist/dotsim-<version>-<platform>.zip (`make addon`).

Each zip holds the add-on's modules, a blender_manifest.toml made from
blender_manifest.template.toml, and under wheels/ dotsim itself and the dependencies the preview
imports, built for Blender's Python 3.11 on that platform. Blender unpacks the wheels when the
extension is enabled, so nothing is downloaded then. Blender's own extension builder (bundled with
the bpy module) validates the manifest, drops the wheels of other platforms and writes one zip per
platform.

Wheels come from PyPI (`pip download`, kept in build/addon_wheels/<platform>/ for the next build)
or, with --from-venv, from the distributions installed in this Python (this machine's platform
only; no network). Runs without bpy being imported; docs/ADDON.md describes the result.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import importlib.metadata
import importlib.util
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

from dotsim.version import __version__

ADDON_DIR = Path(__file__).resolve().parent
REPO = ADDON_DIR.parent
MANIFEST_TEMPLATE = ADDON_DIR / "blender_manifest.template.toml"
BLENDER_PYTHON = "3.11"  # Blender 4.2 to 5.0 bundle CPython 3.11
# What the preview imports besides dotsim and what Blender bundles (numpy, Cython, requests and
# zstandard: the bpy module's own requirements). Found by running the panel's operators with an
# import hook; tests/blender_addon/test_blender_extension.py checks that each of these is imported and that
# nothing else is missing. Versions: the ones installed here, which the tests run with.
PREVIEW_DISTRIBUTIONS = (
    "opencv-contrib-python-headless",  # dotsim.pattern_store: pattern resizing
    "scipy",  # dotsim.patterns, generator.scene_spec, procedural textures
    "scikit-image", "lazy-loader", "packaging",  # procedural textures (resize)
    "trimesh", "manifold3d", "networkx", "pillow",  # assets_manifest (imported with its package)
    "PyYAML",  # dotsim.rig.calibration_formats: ROS camera_info and Kalibr rig files
)


def _manylinux(machine: str) -> tuple[str, ...]:
    return (*(f"manylinux_2_{minor}_{machine}" for minor in range(28, 16, -1)), f"manylinux2014_{machine}")


# pip's --platform tags for each Blender platform. pip expands a macOS tag to older macOS versions
# but not a manylinux tag to older glibc versions, so those are listed (Blender 4.2 needs glibc
# 2.28). macOS 14 is the newest a wheel may require (OpenCV 4.11's need macOS 13).
PIP_PLATFORMS = {
    "linux-x64": _manylinux("x86_64"),
    "linux-arm64": _manylinux("aarch64"),
    "macos-arm64": ("macosx_14_0_arm64",),
    "macos-x64": ("macosx_14_0_x86_64",),
    "windows-x64": ("win_amd64",),
    "windows-arm64": ("win_arm64",),
}


class ExtensionBuildError(RuntimeError):
    """A build step failed; the message names the step, package or platform."""


def this_platform() -> str:
    """This machine's platform in Blender's spelling (linux-x64, macos-arm64, windows-x64, ...)."""
    system, _, machine = sysconfig.get_platform().partition("-")  # linux-x86_64, macosx-11.0-arm64, win-amd64
    system = {"macosx": "macos", "win": "windows"}.get(system, system)
    machine = machine.rpartition("-")[2]
    return f"{system}-{ {'x86_64': 'x64', 'amd64': 'x64', 'aarch64': 'arm64'}.get(machine, machine)}"


def pinned_requirements(names=PREVIEW_DISTRIBUTIONS) -> list[str]:
    """`name==version` of each distribution as installed in this Python."""
    try:
        return [f"{name}=={importlib.metadata.version(name)}" for name in names]
    except importlib.metadata.PackageNotFoundError as error:
        raise ExtensionBuildError(f"{error.name} is not installed here; `make setup` installs it") from None


def _wheel_name(requirement: str) -> str:
    """The file-name prefix of a requirement's wheels (`opencv-contrib-python-headless==4.11.0.86`
    -> `opencv_contrib_python_headless-4.11.0.86-`)."""
    name, _, version = requirement.partition("==")
    return f"{re.sub(r'[-_.]+', '_', name).lower()}-{version}-"


def _cached_wheel(folder: Path, requirement: str) -> Path | None:
    prefix = _wheel_name(requirement)
    return next((p for p in sorted(folder.glob("*.whl")) if p.name.lower().startswith(prefix)), None)


def download_wheels(requirements: list[str], platform: str, cache: Path) -> list[Path] | None:
    """The wheels of `requirements` for Blender's Python on `platform`, from `cache`/<platform> or
    downloaded there from PyPI. None when PyPI has no wheel of some requirement for it (printed)."""
    folder = cache / platform
    folder.mkdir(parents=True, exist_ok=True)
    wheels = []
    for requirement in requirements:
        if (wheel := _cached_wheel(folder, requirement)) is None:
            command = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
                       "--python-version", BLENDER_PYTHON, "--implementation", "cp",
                       *(f"--platform={tag}" for tag in PIP_PLATFORMS[platform]), "--dest", str(folder),
                       requirement]
            result = subprocess.run(command, capture_output=True, text=True)
            wheel = _cached_wheel(folder, requirement)
            if result.returncode != 0 or wheel is None:
                reason = result.stderr.strip().splitlines()[-1] if result.stderr.strip() else "pip found none"
                print(f"{platform}: no wheel of {requirement} for Python {BLENDER_PYTHON} ({reason}); "
                      "platform left out")
                return None
        wheels.append(wheel)
    return wheels


def _record_hash(data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"sha256={digest}"


def wheel_from_installed(name: str, out_dir: Path) -> Path:
    """A wheel of distribution `name` packed from its files installed in this Python (the files its
    RECORD lists inside site-packages; scripts and compiled caches left out), named with the tags of
    its WHEEL file. Deflated at level 1, the fastest: the linux-x64 zip shrinks from 320 to 123 MiB."""
    dist = importlib.metadata.distribution(name)
    tags = [line.split(":", 1)[1].strip() for line in (dist.read_text("WHEEL") or "").splitlines()
            if line.startswith("Tag:")]
    if not tags:
        raise ExtensionBuildError(f"{name}: installed without a WHEEL file naming its tags; cannot repack it")
    interpreters, abis, platforms = (sorted({tag.split("-")[i] for tag in tags}, key=str) for i in range(3))
    dist_info = next(str(f).split("/")[0] for f in dist.files if str(f).split("/")[0].endswith(".dist-info"))
    distribution, version = dist_info.removesuffix(".dist-info").rsplit("-", 1)
    tag = "-".join(".".join(part) for part in (interpreters, abis, platforms))
    wheel = out_dir / f"{distribution}-{version}-{tag}.whl"
    files = sorted(str(f) for f in dist.files
                   if not str(f).startswith("..") and "__pycache__" not in str(f)
                   and not str(f).endswith(("RECORD", "INSTALLER", "REQUESTED", "direct_url.json")))
    temporary = wheel.with_name(f".{wheel.name}.{os.getpid()}")
    record = []
    with zipfile.ZipFile(temporary, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for relative in files:
            data = Path(dist.locate_file(relative)).read_bytes()
            archive.writestr(relative, data)
            record.append(f"{relative},{_record_hash(data)},{len(data)}")
        record.append(f"{dist_info}/RECORD,,")
        archive.writestr(f"{dist_info}/RECORD", "\n".join(record) + "\n")
    os.replace(temporary, wheel)
    return wheel


def dotsim_wheel(out_dir: Path) -> Path:
    """dotsim's own wheel, built from this checkout with the installed setuptools (no download)."""
    # setuptools copies the packages into build/lib and packs all it finds there: clear it, or a
    # module deleted from the checkout since the last build would still be shipped.
    shutil.rmtree(REPO / "build" / "lib", ignore_errors=True)
    result = subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
                             "--no-build-isolation", "--wheel-dir", str(out_dir), str(REPO)],
                            capture_output=True, text=True)
    wheel = _cached_wheel(out_dir, f"dotsim=={__version__}")
    if result.returncode != 0 or wheel is None:
        raise ExtensionBuildError(f"building dotsim's wheel failed: {result.stderr.strip()[-2000:]}")
    return wheel


def manifest_text(version: str, platforms: list[str], wheels: list[str]) -> str:
    """blender_manifest.toml: the template with version, platforms and wheel paths filled in."""
    def toml_list(items):
        return ", ".join(f'"{item}"' for item in items)

    return MANIFEST_TEMPLATE.read_text().format(version=version, platforms=toml_list(platforms),
                                                wheels=toml_list(f"./wheels/{w}" for w in wheels))


def addon_modules() -> list[Path]:
    """The add-on's own modules (this build script is not part of it)."""
    return [p for p in sorted(ADDON_DIR.glob("*.py")) if p.name != Path(__file__).name]


def blender_extension_tool() -> Path:
    """blender_ext.py, Blender's extension command line (`blender --command extension`), as the
    installed bpy module bundles it."""
    spec = importlib.util.find_spec("bpy")
    for folder in (spec.submodule_search_locations or []) if spec else []:
        found = sorted(Path(folder).glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
        if found:
            return found[-1]
    raise ExtensionBuildError("Blender's extension builder (bpy/*/scripts/addons_core/bl_pkg/cli/"
                              "blender_ext.py) not found: install the bpy module (`make setup`)")


def build_extension(out_dir: Path, platforms: list[str], from_venv: bool = False,
                    cache: Path = REPO / "build" / "addon_wheels",
                    staging: Path = REPO / "build" / "addon") -> list[Path]:
    """Build dist zips, one per platform that has every wheel; their paths.

    from_venv: pack the dependency wheels from this Python's installed distributions instead of
    downloading them (only `this_platform()` can be built then).
    """
    unknown = [p for p in platforms if p not in PIP_PLATFORMS]
    if unknown:
        raise ExtensionBuildError(f"platform {', '.join(unknown)}: allowed: {', '.join(PIP_PLATFORMS)}")
    if from_venv and platforms != [this_platform()]:
        raise ExtensionBuildError(f"--from-venv builds only this machine's platform ({this_platform()}), "
                                  f"not {', '.join(platforms)}")
    version = __version__
    shutil.rmtree(staging, ignore_errors=True)
    (staging / "wheels").mkdir(parents=True)
    for module in addon_modules():
        shutil.copy2(module, staging / module.name)
    wheels = [dotsim_wheel(staging / "wheels")]
    built = []
    requirements = pinned_requirements()
    for platform in platforms:
        if from_venv:
            found = [wheel_from_installed(r.partition("==")[0], staging / "wheels") for r in requirements]
        else:
            found = download_wheels(requirements, platform, cache)
        if found is None:
            continue
        built.append(platform)
        for wheel in found:
            if not (staging / "wheels" / wheel.name).exists():
                shutil.copy2(wheel, staging / "wheels" / wheel.name)
            wheels.append(staging / "wheels" / wheel.name)
    if not built:
        raise ExtensionBuildError(f"no platform of {', '.join(platforms)} has all wheels; nothing built")
    (staging / "blender_manifest.toml").write_text(
        manifest_text(version, built, sorted({w.name for w in wheels})))
    out_dir.mkdir(parents=True, exist_ok=True)
    # Blender's builder validates the manifest and writes each zip under a temporary name first.
    result = subprocess.run([sys.executable, str(blender_extension_tool()), "build", "--source-dir",
                             str(staging), "--output-dir", str(out_dir), "--split-platforms"],
                            capture_output=True, text=True)
    if result.returncode != 0:
        output = (result.stdout + result.stderr).strip()
        raise ExtensionBuildError(f"Blender's extension build failed: {output}")
    return [out_dir / f"dotsim-{version}-{platform.replace('-', '_')}.zip" for platform in built]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m blender_addon.build_extension",
        description="Build the dotsim Blender extension: dist/dotsim-<version>-<platform>.zip per platform "
                    "(docs/ADDON.md).")
    parser.add_argument("--platform", action="append", choices=sorted(PIP_PLATFORMS), dest="platforms",
                        help="Blender platform to build for (repeatable; default: each that PyPI has "
                             "wheels for)")
    parser.add_argument("--out", type=Path, default=REPO / "dist", help="output folder (default: dist/)")
    parser.add_argument("--from-venv", action="store_true",
                        help="pack the dependency wheels from this Python's installed packages instead of "
                             "downloading them (this machine's platform only; works offline)")
    args = parser.parse_args(argv)
    platforms = args.platforms or ([this_platform()] if args.from_venv else list(PIP_PLATFORMS))
    try:
        zips = build_extension(args.out, platforms, from_venv=args.from_venv)
    except ExtensionBuildError as error:
        print(f"error: {error}", file=sys.stderr)
        return 1
    for path in zips:
        print(f"{path}: {path.stat().st_size / 2**20:.1f} MiB")
    print(f"built {len(zips)} of {len(platforms)} platforms into {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
