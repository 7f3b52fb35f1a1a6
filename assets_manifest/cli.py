"""`dotsim assets build|check`: build a split's asset cache, or check the manifests and caches."""

import os
import sys
from pathlib import Path

from assets_manifest.cache import (
    DEFAULT_CACHE_DIR,
    AssetCacheError,
    asset_file_problem,
    build_asset_cache,
    cache_index_path,
    default_manifest_path,
    load_asset_cache,
)
from assets_manifest.manifest import ManifestError, find_overlaps, load_manifest
from assets_manifest.mesh_arrays import MeshError, load_mesh_npz
from dotsim.command_options import add_no_progress, add_output
from dotsim.option_types import integer
from dotsim.output_folder import ASSET_CACHE, check_output_folder

SPLITS = ("train", "test")


def _build(args) -> int:
    check_output_folder(args.cache, ASSET_CACHE, "--cache", "dotsim assets build")  # before anything is built
    manifest_path = Path(args.manifest) if args.manifest else default_manifest_path(args.split)
    try:
        manifest = load_manifest(manifest_path)
        summary = build_asset_cache(
            manifest,
            args.cache,
            args.split,
            workers=args.workers or os.cpu_count() or 1,
            progress=not args.no_progress,
        )
    except ManifestError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"cache: {Path(args.cache) / args.split}")
    return 0 if manifest.assets and len(summary.skipped) < len(manifest.assets) else 1


def _validate_mesh_file(path: str) -> str | None:
    """Why a cached mesh is invalid, or None: UVs in [0,1], unit normals, faces in range."""
    import numpy as np

    try:
        arrays = load_mesh_npz(path)
    except (MeshError, OSError, ValueError) as exc:
        return str(exc)
    uvs, normals, faces = arrays["uvs"], arrays["normals"], arrays["faces"]
    if not (np.isfinite(uvs).all() and uvs.min() >= 0 and uvs.max() <= 1):
        return "UVs outside [0,1] or not finite"
    if not np.isfinite(normals).all() or np.abs(np.linalg.norm(normals, axis=1) - 1).max() > 1e-3:
        return "normals not finite or not unit length"
    if faces.min() < 0 or faces.max() >= len(arrays["vertices"]):
        return "face indices out of range"
    return None


def _check(args) -> int:
    problems = []
    manifests = {}
    for split, given in (("train", args.train_manifest), ("test", args.test_manifest)):
        try:
            manifests[split] = load_manifest(given or default_manifest_path(split))
        except ManifestError as exc:
            problems.append(str(exc))
    indexes = {}
    for split in SPLITS:
        try:
            # Every file is checked below, each mismatch its own problem (verify=True stops at the first).
            cache = load_asset_cache(args.cache, split, verify=False)
        except AssetCacheError as exc:
            if cache_index_path(args.cache, split).exists():
                problems.append(str(exc))  # a cache that is there but cannot be used
            else:
                print(f"note: {exc}")  # a split not built
            continue
        indexes[split] = cache.index
        damaged = set()
        for entry in cache.meshes + cache.textures:
            problem = asset_file_problem(Path(entry.path), entry.sha256)
            if problem:
                problems.append(problem)
                damaged.add(entry.path)
        if split in manifests and cache.index["manifest"]["sha256"] != manifests[split].sha256:
            problems.append(
                f"cache {cache.root} was built from another manifest: rebuild with "
                f"`dotsim assets build --split {split} --cache {args.cache}`"
            )
        for entry in cache.meshes:
            reason = None if entry.path in damaged else _validate_mesh_file(entry.path)
            if reason:
                problems.append(f"{entry.path}: {reason}")
        print(f"{split}: {len(cache.meshes)} meshes, {len(cache.textures)} textures checked in {cache.root}"
              f"{f' ({len(damaged)} damaged)' if damaged else ''}")
    if len(manifests) == 2:
        problems += find_overlaps(
            manifests["train"], manifests["test"], indexes.get("train"), indexes.get("test")
        )
    for problem in problems:
        print(f"problem: {problem}")
    compared = (
        "manifests and built caches"
        if len(indexes) == 2
        else "manifests (build both caches to compare content)"
    )
    print(f"assets check: {len(problems)} problem(s); train/test disjointness checked on {compared}")
    return 1 if problems else 0


def _preview(args) -> int:
    from assets_manifest.preview import contact_sheet
    from dotsim.images import ImageError, write_image

    try:
        cache = load_asset_cache(args.cache, args.split)
    except AssetCacheError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.output or f"assets_{args.split}.png")
    try:
        write_image(out, contact_sheet(cache, count=args.count))
    except ImageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"wrote {out}: {min(args.count, len(cache.meshes))} meshes and "
        f"{min(args.count, len(cache.textures))} textures of the {args.split} cache"
    )
    return 0


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser(
        "assets",
        help="build and check the train/test asset caches (meshes with UVs, textures)",
        description="Build the asset cache of a split from its manifest (docs/ASSETS.md), or check that "
        "the train and test manifests and caches are valid and share no asset.",
    )
    actions = parser.add_subparsers(dest="assets_command", metavar="ACTION", required=True)

    build = actions.add_parser(
        "build",
        help="build or update CACHE/<split>/ from the split's manifest",
        description="Build CACHE/<split>/{meshes/*.npz, textures/*.png, index.json} from a manifest. "
        "Reproducible (same manifest -> same checksums), incremental (only assets whose source "
        "changed are rebuilt; an interrupted build resumes) and atomic. Unreadable, empty or "
        "degenerate inputs are skipped with a report line. Exit status 1 if nothing could be built, "
        "2 for an invalid manifest.",
    )
    build.add_argument("--split", required=True, choices=SPLITS, help="which split to build")
    build.add_argument(
        "--cache", default=DEFAULT_CACHE_DIR, help=f"cache directory (default: {DEFAULT_CACHE_DIR})"
    )
    build.add_argument(
        "--manifest",
        help="manifest TOML to build from (default: the manifest dotsim ships for the split, "
        "assets_manifest/manifests/<split>.toml)",
    )
    build.add_argument(
        "--workers",
        type=integer(0),
        default=0,
        help="processes building assets in parallel (default 0: one per CPU core); the result does not "
        "depend on it",
    )
    add_no_progress(build)
    build.set_defaults(func=_build)

    check = actions.add_parser(
        "check",
        help="validate manifests and caches; fail if train and test share an asset",
        description="Validate both manifests; verify each built cache (file checksums, mesh UVs in "
        "[0,1], unit normals); fail when train and test share an asset: the same source "
        "(family + params + seed, user-file content, package image) or, for built caches, the same "
        "resulting mesh or image. Exit status 1 when there is any problem.",
    )
    check.add_argument(
        "--cache", default=DEFAULT_CACHE_DIR, help=f"cache directory (default: {DEFAULT_CACHE_DIR})"
    )
    check.add_argument("--train-manifest", help="train manifest (default: the shipped train.toml)")
    check.add_argument("--test-manifest", help="test manifest (default: the shipped test.toml)")
    check.set_defaults(func=_check)

    preview = actions.add_parser(
        "preview",
        help="contact sheet PNG of a built cache (meshes with a UV checker, textures)",
        description="Draw a grid of meshes (shaded, with a UV checkerboard, so seams and stretching "
        "show) and textures, spread evenly over the split's cache, into a PNG.",
    )
    preview.add_argument("--split", required=True, choices=SPLITS, help="which split to show")
    preview.add_argument(
        "--cache", default=DEFAULT_CACHE_DIR, help=f"cache directory (default: {DEFAULT_CACHE_DIR})"
    )
    add_output(preview, "PNG to write (default: assets_<split>.png)", metavar="PNG", required=False,
               old=("--output",), dest="output")
    preview.add_argument("--count", type=integer(1), default=24, help="meshes and textures each (default 24)")
    preview.set_defaults(func=_preview)
