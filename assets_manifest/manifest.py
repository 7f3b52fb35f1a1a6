"""Asset manifests: load and validate a split's TOML manifest, expand it into one spec per asset, and
check that two splits share no asset.

Format (documented in docs/ASSETS.md):

    [split]
    name = "train"
    clutter_density = 1.0              # multiplier on the generator's object-count range

    [[meshes]]                         # a procedural family over a seed range
    name = "blob"
    generator = "noise_displaced_sphere"
    seeds = [0, 60]                    # half-open: seeds 0..59
    params = { amplitude = [0.05, 0.25] }
    scale = [0.05, 0.4]                # metres, the largest extent the generator should give it
    license = "CC0-1.0"

    [[meshes]]                         # every OBJ/PLY/STL/GLB below a folder (relative to this file)
    name = "my_objects"
    folder = "user_meshes"
    scale = [0.1, 0.8]
    license = "as the owner says"

    [[textures]]
    name = "photos"
    skimage = ["brick", "camera"]      # photographs bundled in scikit-image's wheel
    scale = [0.2, 1.0]                 # metres per texture tile

A single file is `file = "path"` with an optional `sha256 = "..."` pin, checked before building.
Each asset's identity (its *source key*) is the canonical JSON of what makes it: family + params +
seed, the content hash of a user file, or the scikit-image image name. Names, licenses and scale
hints are not part of it, so renaming an entry does not hide an overlap between splits.
"""

import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

from assets_manifest.package_images import SKIMAGE_PHOTOS
from assets_manifest.params import canonical_json, check_params
from assets_manifest.procedural_meshes import MESH_FAMILIES
from assets_manifest.procedural_textures import TEXTURE_FAMILIES
from dotsim.file_io import sha256_bytes, sha256_file

MESH_EXTENSIONS = (".obj", ".ply", ".stl", ".glb", ".gltf", ".off")
IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")
_ENTRY_KEYS = {
    "name",
    "generator",
    "seeds",
    "params",
    "folder",
    "file",
    "sha256",
    "skimage",
    "scale",
    "license",
}


class ManifestError(ValueError):
    """A manifest that cannot be used; the message names the file, entry and field."""


@dataclass(frozen=True)
class AssetSpec:
    """One asset a manifest asks for. `source` is JSON-safe and, with the builder version, keys the
    incremental build; `source_key` is the identity used for disjointness."""

    id: str
    kind: str  # "mesh" | "texture"
    entry: str
    source: dict = field(hash=False)
    license: str
    scale_hint: tuple[float, float]

    @property
    def source_key(self) -> str:
        # A user file is identified by its content, not where it lies: the same file copied into
        # both splits' folders is still one asset.
        return canonical_json({k: v for k, v in self.source.items() if k != "file"})


@dataclass(frozen=True)
class Manifest:
    path: Path
    sha256: str
    split: str
    clutter_density: float
    meshes: list[AssetSpec]
    textures: list[AssetSpec]

    @property
    def assets(self) -> list[AssetSpec]:
        return self.meshes + self.textures


def _scale_hint(entry: dict, where: str) -> tuple[float, float]:
    scale = entry.get("scale")
    if (
        not isinstance(scale, list)
        or len(scale) != 2
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in scale)
        or not 0 < scale[0] <= scale[1]
    ):
        raise ManifestError(f"{where}: 'scale' must be [lo, hi] metres with 0 < lo <= hi, got {scale!r}")
    return float(scale[0]), float(scale[1])


def _sanitize(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", text).strip("_.") or "asset"


def _files_under(folder: Path, extensions: tuple[str, ...]) -> list[Path]:
    return sorted(
        p
        for p in folder.rglob("*")
        if p.is_file() and p.suffix.lower() in extensions and not p.name.startswith(".")
    )


def _expand_entry(entry: dict, kind: str, base: Path, where: str) -> list[AssetSpec]:
    unknown = set(entry) - _ENTRY_KEYS
    if unknown:
        raise ManifestError(f"{where}: unknown field(s) {sorted(unknown)}; allowed: {sorted(_ENTRY_KEYS)}")
    name = entry.get("name")
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ManifestError(
            f"{where}: 'name' must be a string of letters, digits, '_', '.', '-', got {name!r}"
        )
    where = f"{where} ({name!r})"
    sources = [k for k in ("generator", "folder", "file", "skimage") if k in entry]
    if len(sources) != 1:
        raise ManifestError(f"{where}: give exactly one of generator, folder, file, skimage; got {sources}")
    scale = _scale_hint(entry, where)
    license_ = entry.get("license")
    families = MESH_FAMILIES if kind == "mesh" else TEXTURE_FAMILIES

    def spec(asset_id: str, source: dict, lic: str | None = None) -> AssetSpec:
        lic = lic or license_
        if not isinstance(lic, str) or not lic:
            raise ManifestError(f"{where}: 'license' (a non-empty string) is required")
        return AssetSpec(asset_id, kind, name, source, lic, scale)

    if "generator" in entry:
        family = entry["generator"]
        if family not in families:
            raise ManifestError(
                f"{where}: unknown {kind} generator {family!r}; known: {', '.join(sorted(families))}"
            )
        seeds = entry.get("seeds")
        if (
            not isinstance(seeds, list)
            or len(seeds) != 2
            or not all(type(s) is int for s in seeds)
            or not 0 <= seeds[0] < seeds[1]
        ):
            raise ManifestError(
                f"{where}: 'seeds' must be [first, stop) integers with 0 <= first < stop, got {seeds!r}"
            )
        params = entry.get("params", {})
        if not isinstance(params, dict):
            raise ManifestError(f"{where}: 'params' must be a table, got {params!r}")
        problems = check_params(params, families[family].defaults, where)
        if problems:
            raise ManifestError("\n".join(problems))
        return [
            spec(f"{name}_{seed:04d}", {"generator": family, "params": params, "seed": seed})
            for seed in range(*seeds)
        ]
    if "skimage" in entry:
        names = entry["skimage"]
        if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
            raise ManifestError(f"{where}: 'skimage' must be a non-empty list of image names")
        if kind != "texture":
            raise ManifestError(f"{where}: 'skimage' images are textures, not meshes")
        for n in names:
            if n not in SKIMAGE_PHOTOS:
                raise ManifestError(
                    f"{where}: unknown scikit-image photograph {n!r}; "
                    f"known: {', '.join(sorted(SKIMAGE_PHOTOS))}"
                )
        return [spec(f"{name}_{n}", {"skimage": n}, license_ or SKIMAGE_PHOTOS[n].license) for n in names]

    extensions = MESH_EXTENSIONS if kind == "mesh" else IMAGE_EXTENSIONS
    if "folder" in entry:
        folder = (base / Path(entry["folder"]).expanduser()).resolve()
        if not folder.is_dir():
            raise ManifestError(f"{where}: folder {str(folder)!r} does not exist")
        files = _files_under(folder, extensions)
        if not files:
            raise ManifestError(f"{where}: folder {str(folder)!r} holds no {'/'.join(extensions)} files")
    else:
        path = (base / Path(entry["file"]).expanduser()).resolve()
        if not path.is_file():
            raise ManifestError(f"{where}: file {str(path)!r} does not exist")
        if path.suffix.lower() not in extensions:
            raise ManifestError(f"{where}: {str(path)!r} is not one of {', '.join(extensions)}")
        folder, files = path.parent, [path]
    out = []
    for path in files:
        digest = sha256_file(path)
        if "sha256" in entry and digest != entry["sha256"]:
            raise ManifestError(f"{where}: {path} has sha256 {digest}, the manifest pins {entry['sha256']}")
        stem = _sanitize(str(path.relative_to(folder).with_suffix("")))
        out.append(spec(f"{name}_{stem}", {"file": str(path), "file_sha256": digest}))
    return out


def load_manifest(path: str | Path) -> Manifest:
    """Read and validate a manifest; expand every entry into AssetSpecs. Raises ManifestError naming
    the file, entry and field for anything wrong (before anything is built)."""
    path = Path(path).resolve()
    try:
        raw = path.read_bytes()
        data = tomllib.loads(raw.decode("utf-8"))
    except FileNotFoundError:
        raise ManifestError(f"manifest {path} does not exist") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ManifestError(f"manifest {path} is not valid TOML: {exc}") from None
    unknown = set(data) - {"split", "meshes", "textures"}
    if unknown:
        raise ManifestError(
            f"{path}: unknown top-level key(s) {sorted(unknown)}; allowed: split, meshes, textures"
        )
    split = data.get("split", {})
    name = split.get("name")
    if not isinstance(name, str) or not _NAME_RE.match(name):
        raise ManifestError(f"{path}: [split] name must be a word such as 'train' or 'test', got {name!r}")
    density = split.get("clutter_density", 1.0)
    if not isinstance(density, int | float) or isinstance(density, bool) or not density > 0:
        raise ManifestError(f"{path}: [split] clutter_density must be a positive number, got {density!r}")
    expanded = {}
    for kind, key in (("mesh", "meshes"), ("texture", "textures")):
        entries = data.get(key, [])
        if not isinstance(entries, list):
            raise ManifestError(f"{path}: '{key}' must be an array of tables ([[{key}]])")
        specs: list[AssetSpec] = []
        for i, entry in enumerate(entries):
            specs += _expand_entry(entry, kind, path.parent, f"{path}: {key}[{i}]")
        expanded[key] = specs
    ids = [a.id for a in expanded["meshes"] + expanded["textures"]]
    duplicates = sorted({i for i in ids if ids.count(i) > 1})
    if duplicates:
        raise ManifestError(f"{path}: asset ids appear twice (entry names must be unique): {duplicates[:10]}")
    return Manifest(
        path, sha256_bytes(raw), name, float(density), expanded["meshes"], expanded["textures"]
    )


def _same_source_overlaps(a: Manifest, b: Manifest) -> list[str]:
    by_key = {spec.source_key: spec for spec in a.assets}
    return [
        f"same source: {a.split} {by_key[spec.source_key].id} and {b.split} {spec.id} "
        f"are both {spec.source_key}"
        for spec in b.assets
        if spec.source_key in by_key
    ]


def _same_content_overlaps(index_a: dict, index_b: dict) -> list[str]:
    def by_content(index):
        return {e["content_sha256"]: e["id"] for e in index.get("meshes", []) + index.get("textures", [])}

    content_a = by_content(index_a)
    return [
        f"same content: {index_a['split']} {content_a[digest]} and {index_b['split']} {asset_id} "
        f"(content sha256 {digest[:12]})"
        for digest, asset_id in sorted(by_content(index_b).items())
        if digest in content_a
    ]


def find_overlaps(
    a: Manifest, b: Manifest, index_a: dict | None = None, index_b: dict | None = None
) -> list[str]:
    """Every asset two splits share: the same source (family + params + seed, user-file content, or
    package image), and, given their built cache indexes, the same resulting mesh or image."""
    overlaps = _same_source_overlaps(a, b)
    if index_a is not None and index_b is not None:
        overlaps += _same_content_overlaps(index_a, index_b)
    return overlaps


def check_disjoint(
    a: Manifest, b: Manifest, index_a: dict | None = None, index_b: dict | None = None
) -> None:
    """Raise ManifestError listing the shared assets when two splits are not disjoint."""
    overlaps = find_overlaps(a, b, index_a, index_b)
    if overlaps:
        shown = "\n  ".join(overlaps[:20])
        more = f"\n  ... and {len(overlaps) - 20} more" if len(overlaps) > 20 else ""
        raise ManifestError(f"{a.path} and {b.path} share {len(overlaps)} asset(s):\n  {shown}{more}")
