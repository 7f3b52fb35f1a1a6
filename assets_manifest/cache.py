"""The asset cache: build it from a manifest (reproducible, incremental, atomic) and load it.

Layout (docs/ASSETS.md):
    CACHE_DIR/<split>/index.json
    CACHE_DIR/<split>/meshes/<asset_id>.npz     see mesh_arrays.py for the arrays
    CACHE_DIR/<split>/textures/<asset_id>.png   8- or 16-bit grey reflectance

Each asset is keyed by a hash of its source spec and BUILDER_VERSION; a rebuild reuses every asset
whose key and file checksum are unchanged, so only what changed is built again. Files are written
under a temporary name and renamed; the index is rewritten (atomically) every few assets with
"complete": false, so an interrupted build resumes where it stopped.
"""

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from assets_manifest.images import ImageError, png_bytes, texture_from_image
from assets_manifest.manifest import AssetSpec, Manifest, ManifestError
from assets_manifest.mesh_arrays import MeshError, arrays_sha256, finalize_mesh, npz_bytes
from assets_manifest.package_images import skimage_image_path
from assets_manifest.params import canonical_json, sample_params, spec_seed
from assets_manifest.procedural_meshes import MESH_FAMILIES
from assets_manifest.procedural_textures import TEXTURE_FAMILIES
from assets_manifest.user_folders import load_image_file, load_mesh_file
from dotsim.file_io import TMP_PREFIX, atomic_write_bytes, make_folder, sha256_bytes, sha256_file
from dotsim.version import __version__

CACHE_FORMAT = "dotsim-assets/1"
# Bump when any builder's output for the same source spec changes: every asset is then rebuilt.
BUILDER_VERSION = "1"
DEFAULT_CACHE_DIR = "assets_cache"
MANIFEST_DIR = Path(__file__).parent / "manifests"
_INDEX_SAVE_EVERY = 25


class AssetCacheError(RuntimeError):
    """A missing, incomplete or invalid asset cache; the message says which file and what to run."""


@dataclass(frozen=True)
class AssetEntry:
    """One built asset. `path` is absolute; `scale_hint` is (lo, hi) metres: the largest extent to
    give a mesh, or the size of one texture tile."""

    id: str
    kind: str
    path: str
    scale_hint: tuple[float, float]
    sha256: str
    content_sha256: str
    license: str
    source: dict = field(hash=False)


@dataclass(frozen=True)
class AssetCache:
    """A split's built assets. `clutter_density` multiplies the generator's object-count range
    (index key "clutter_density"; the test split's differs from train's)."""

    split: str
    root: Path
    clutter_density: float
    meshes: list[AssetEntry]
    textures: list[AssetEntry]
    index: dict = field(hash=False)


@dataclass
class BuildSummary:
    split: str
    built: list[str] = field(default_factory=list)
    reused: list[str] = field(default_factory=list)
    skipped: list[dict] = field(default_factory=list)  # {"id", "source", "reason"}
    removed: list[str] = field(default_factory=list)
    seconds: float = 0.0

    def line(self) -> str:
        return (
            f"assets {self.split}: {len(self.built)} built, {len(self.reused)} reused, "
            f"{len(self.skipped)} skipped, {len(self.removed)} removed in {self.seconds:.1f} s"
        )


def default_manifest_path(split: str) -> Path:
    """The manifest shipped with dotsim for `split` (assets_manifest/manifests/<split>.toml)."""
    return MANIFEST_DIR / f"{split}.toml"


def cache_index_path(cache_dir: str | Path, split: str) -> Path:
    """Where the index.json of a split's cache lives."""
    return Path(cache_dir) / split / "index.json"


def _rebuild_hint(cache_dir, split) -> str:
    return f"run `dotsim assets build --split {split} --cache {cache_dir}`"


def read_index(cache_dir: str | Path, split: str) -> dict:
    """The parsed index.json of a split; AssetCacheError if missing, unreadable or incomplete."""
    path = cache_index_path(cache_dir, split)
    hint = _rebuild_hint(cache_dir, split)
    if not path.is_file():
        raise AssetCacheError(f"no asset cache index at {path}: {hint}")
    try:
        index = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise AssetCacheError(f"asset cache index {path} is unreadable ({exc}): {hint}") from None
    if not isinstance(index, dict) or index.get("format") != CACHE_FORMAT:
        found = index.get("format") if isinstance(index, dict) else type(index).__name__
        raise AssetCacheError(
            f"asset cache index {path} has format {found!r}, expected {CACHE_FORMAT!r}: {hint}"
        )
    if not index.get("complete"):
        raise AssetCacheError(f"asset cache index {path} is from an interrupted build: {hint}")
    return index


# What each mesh and texture entry of index.json must hold, and of which JSON type.
ENTRY_KEYS = {"id": str, "kind": str, "path": str, "scale_hint": list, "sha256": str, "content_sha256": str,
              "license": str, "source": dict}


def _check_entry(entry, where: str, hint: str) -> None:
    """AssetCacheError naming the entry and the keys it lacks (or holds of the wrong type)."""
    if not isinstance(entry, dict):
        raise AssetCacheError(f"{where} is not an object: {hint}")
    missing = [key for key in ENTRY_KEYS if key not in entry]
    wrong = [key for key, kind in ENTRY_KEYS.items() if key in entry and not isinstance(entry[key], kind)]
    if missing or wrong:
        what = (f"lacks key(s) {missing}" if missing else "") + (" and " if missing and wrong else "") + \
               (f"has key(s) {wrong} of the wrong type" if wrong else "")
        raise AssetCacheError(f"{where} {what} (needs {', '.join(ENTRY_KEYS)}): {hint}")


def asset_file_problem(path: Path, sha256: str) -> str | None:
    """Why a cached file cannot be used (missing, or not the bytes its index entry records), or None."""
    if not path.is_file():
        return f"asset file {path} listed in {path.parents[1] / 'index.json'} is missing"
    if sha256_file(path) != sha256:
        return f"asset file {path} does not match its sha256 in the index (changed or corrupt)"
    return None


def load_asset_cache(cache_dir: str | Path, split: str, verify: bool = False) -> AssetCache:
    """The built assets of `split` under `cache_dir`. Checks that every index entry holds the keys
    it needs and every listed file exists (and with `verify`, that its sha256 matches); raises
    AssetCacheError naming the index, entry or file and the command that rebuilds it."""
    index = read_index(cache_dir, split)
    root = cache_index_path(cache_dir, split).parent.resolve()
    hint = _rebuild_hint(cache_dir, split)
    if not isinstance(index.get("clutter_density"), int | float):
        raise AssetCacheError(f"asset cache index {root / 'index.json'} lacks a number clutter_density: "
                              f"{hint}")
    lists = {}
    for key in ("meshes", "textures"):
        entries = []
        listed = index.get(key, [])
        if not isinstance(listed, list):
            raise AssetCacheError(f"asset cache index {root / 'index.json'}: {key} is not a list: {hint}")
        for number, e in enumerate(listed):
            _check_entry(e, f"asset cache index {root / 'index.json'}: {key} entry {number}"
                            f"{' (' + str(e['id']) + ')' if isinstance(e, dict) and 'id' in e else ''}", hint)
            path = root / e["path"]
            if not path.is_file() or verify:
                problem = asset_file_problem(path, e["sha256"])
                if problem:
                    raise AssetCacheError(f"{problem}: {hint}")
            entries.append(
                AssetEntry(
                    e["id"],
                    e["kind"],
                    str(path),
                    tuple(e["scale_hint"]),
                    e["sha256"],
                    e["content_sha256"],
                    e["license"],
                    e["source"],
                )
            )
        lists[key] = entries
    return AssetCache(split, root, float(index["clutter_density"]), lists["meshes"], lists["textures"], index)


def asset_key(spec: AssetSpec) -> str:
    """What the built file depends on: kind, source spec and builder version."""
    source = {k: v for k, v in spec.source.items() if k != "file"}
    payload = canonical_json({"kind": spec.kind, "source": source, "builder": BUILDER_VERSION})
    return sha256_bytes(payload.encode())


def _build_mesh(spec: AssetSpec) -> dict[str, np.ndarray]:
    source = spec.source
    if "generator" in source:
        family = MESH_FAMILIES[source["generator"]]
        rng = np.random.default_rng(spec_seed(source))
        mesh = family.make(sample_params(source["params"], family.defaults, rng), rng)
        return finalize_mesh(mesh.vertices, mesh.faces)
    return finalize_mesh(*load_mesh_file(source["file"]))


def _build_texture(spec: AssetSpec) -> np.ndarray:
    source = spec.source
    if "generator" in source:
        family = TEXTURE_FAMILIES[source["generator"]]
        rng = np.random.default_rng(spec_seed(source))
        return texture_from_image(family.make(sample_params(source["params"], family.defaults, rng), rng))
    if "skimage" in source:
        path = skimage_image_path(source["skimage"])
        if not path.is_file():
            raise ImageError(f"scikit-image {source['skimage']!r} is not bundled in this install ({path})")
        return texture_from_image(load_image_file(path))
    return texture_from_image(load_image_file(source["file"]))


def _build_one(spec: AssetSpec) -> tuple[str, bytes, str, dict]:
    """(relative path, file bytes, content sha256, extra index fields) of one asset."""
    if spec.kind == "mesh":
        arrays = _build_mesh(spec)
        extra = {"vertices": len(arrays["vertices"]), "faces": len(arrays["faces"])}
        return f"meshes/{spec.id}.npz", npz_bytes(arrays), arrays_sha256(arrays), extra
    image = _build_texture(spec)
    extra = {"width": image.shape[1], "height": image.shape[0], "bit_depth": image.dtype.itemsize * 8}
    return f"textures/{spec.id}.png", png_bytes(image), arrays_sha256({"image": image}), extra


def _describe_source(spec: AssetSpec) -> str:
    s = spec.source
    if "generator" in s:
        return f"{s['generator']} seed {s['seed']}"
    return f"scikit-image {s['skimage']}" if "skimage" in s else s["file"]


def _versions() -> dict:
    import cv2
    import skimage
    import trimesh
    import xatlas

    return {
        "dotsim": __version__,
        "numpy": np.__version__,
        "trimesh": trimesh.__version__,
        "xatlas": getattr(xatlas, "__version__", "unknown"),
        "scikit-image": skimage.__version__,
        "opencv": cv2.__version__,
    }


def _write_index(root: Path, manifest: Manifest, entries: dict, skipped: list, complete: bool) -> None:
    ordered = [entries[s.id] for s in manifest.assets if s.id in entries]
    versions = _versions()
    index = {
        "format": CACHE_FORMAT,
        "builder_version": BUILDER_VERSION,
        "dotsim_version": versions["dotsim"],
        "split": manifest.split,
        "clutter_density": manifest.clutter_density,
        "complete": complete,
        "manifest": {"path": str(manifest.path), "sha256": manifest.sha256},
        "versions": versions,
        "meshes": [e for e in ordered if e["kind"] == "mesh"],
        "textures": [e for e in ordered if e["kind"] == "texture"],
        "skipped": skipped,
    }
    atomic_write_bytes(root / "index.json", (json.dumps(index, indent=1) + "\n").encode())


def _previous_entries(root: Path) -> dict:
    """Entries of an earlier (possibly interrupted) build, by id; empty when there is none usable."""
    try:
        index = json.loads((root / "index.json").read_text())
    except (OSError, json.JSONDecodeError):
        return {}
    if not isinstance(index, dict) or index.get("format") != CACHE_FORMAT:
        return {}
    return {e["id"]: e for e in index.get("meshes", []) + index.get("textures", [])}


def _try_build(spec: AssetSpec) -> tuple[tuple | None, str | None]:
    """(_build_one's result, None), or (None, why it failed)."""
    try:
        return _build_one(spec), None
    except Exception as exc:  # noqa: BLE001 - one bad asset (or a library failing on it) must not stop the build
        return None, str(exc) if isinstance(exc, MeshError | ImageError) else f"{type(exc).__name__}: {exc}"


def _reusable(old: dict | None, key: str, root: Path) -> bool:
    return bool(
        old
        and old.get("key") == key
        and (root / old["path"]).is_file()
        and sha256_file(root / old["path"]) == old["sha256"]
    )


def build_asset_cache(
    manifest: Manifest,
    cache_dir: str | Path,
    split: str | None = None,
    *,
    workers: int = 1,
    progress: bool = True,
    log=print,
) -> BuildSummary:
    """Build (or bring up to date) CACHE_DIR/<split>/ from `manifest`, with `workers` processes (each
    asset is seeded from its own spec, so the result does not depend on it). An asset that cannot be
    built (unreadable, empty or degenerate mesh; bad image) is skipped with a report line through
    `log`; the build never stops half-way. Returns the summary (also logged as its last line)."""
    from concurrent.futures import ProcessPoolExecutor

    from tqdm import tqdm

    split = split or manifest.split
    if split != manifest.split:
        raise ManifestError(f"{manifest.path} declares split {manifest.split!r}, not {split!r}")
    start = time.perf_counter()
    root = Path(cache_dir) / split
    make_folder(root / "meshes")
    make_folder(root / "textures")
    for leftover in [*root.glob(TMP_PREFIX + "*"), *root.glob("*/" + TMP_PREFIX + "*")]:
        leftover.unlink()  # temporaries of a build that was killed mid-write
    previous = _previous_entries(root)
    summary = BuildSummary(split)
    entries: dict[str, dict] = {}
    todo: list[tuple[AssetSpec, dict]] = []
    for spec in manifest.assets:
        key = asset_key(spec)
        meta = {
            "id": spec.id,
            "kind": spec.kind,
            "source": spec.source,
            "license": spec.license,
            "scale_hint": list(spec.scale_hint),
            "key": key,
        }
        if _reusable(previous.get(spec.id), key, root):
            entries[spec.id] = {**previous[spec.id], **meta}
            summary.reused.append(spec.id)
        else:
            todo.append((spec, meta))
    bar = tqdm(
        total=len(manifest.assets),
        initial=len(summary.reused),
        desc=f"assets {split}",
        unit="asset",
        disable=not progress,
    )
    pool = ProcessPoolExecutor(workers) if workers > 1 and len(todo) > 1 else None
    try:
        results = (
            pool.map(_try_build, [s for s, _ in todo], chunksize=4)
            if pool
            else map(_try_build, [s for s, _ in todo])
        )
        since_save = 0
        for (spec, meta), (result, reason) in zip(todo, results, strict=True):
            bar.update()
            if result is None:
                summary.skipped.append({"id": spec.id, "source": _describe_source(spec), "reason": reason})
                log(f"skipped {spec.id} ({_describe_source(spec)}): {reason}")
                continue
            relative, data, content, extra = result
            atomic_write_bytes(root / relative, data)
            entries[spec.id] = {
                **meta,
                "path": relative,
                "sha256": sha256_bytes(data),
                "content_sha256": content,
                **extra,
            }
            summary.built.append(spec.id)
            since_save += 1
            if since_save >= _INDEX_SAVE_EVERY:
                _write_index(root, manifest, {**previous, **entries}, summary.skipped, complete=False)
                since_save = 0
    finally:
        bar.close()
        if pool:
            pool.shutdown(cancel_futures=True)
    for asset_id, old in previous.items():
        if asset_id not in entries:
            stale = root / old["path"]
            if stale.is_file():
                stale.unlink()
            summary.removed.append(asset_id)
    _write_index(root, manifest, entries, summary.skipped, complete=True)
    summary.seconds = time.perf_counter() - start
    log(summary.line())
    return summary
