"""The files a split's scenes refer to: the projector pattern, built-in textures, the asset cache.

One module for every front end, so they all sample scenes from the same files: `dotsim generate`
(generator/engines/steps.py) keeps the pattern in the dataset (DATASET/pattern.png) and the built-in
textures in DATASET/textures; the Blender add-on (blender_addon/scene_source.py) keeps both in its
work folder (`resources_in_folder`). Everything is made once and reused: a file that exists is the
same image (names carry the split, the texture family and index, or the pattern's sha256).

Every input file a render reads is checked against a sha256 recorded when it was made, never
against itself: built-in textures against textures/checksums.json (written with them; a texture
found without a record is compared with the bytes the generator makes for it), cache meshes and
textures against the cache's index.json. `check_inputs` does it (once per file and process while
the file is unchanged) before a scene is rendered, and the run checks them all up front.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from dotsim.file_io import atomic_write_bytes, atomic_write_json, sha256_bytes, sha256_file
from dotsim.patterns import DotPattern
from generator.config import Config, ConfigError
from generator.sample_scene import MeshAsset, SceneResources, TextureAsset
from generator.scene_spec import SPLITS

TEXTURE_DIR = "textures"
TEXTURE_CHECKSUMS = "checksums.json"
BUILTIN_TEXTURES_PER_FAMILY = 4


class InputChangedError(ConfigError):
    """An input file (texture, mesh, pattern) is missing or no longer has its recorded sha256."""


# (path, size, mtime in ns) -> sha256 of the files this process checked: each hashed once while unchanged.
_CHECKED: dict[tuple[str, int, int], str] = {}


def check_inputs(recorded: dict[str, str], paths) -> None:
    """Raise InputChangedError (one line naming the file) unless each of `paths` that `recorded`
    lists (path -> sha256) has that sha256 now."""
    for path in paths:
        expected = recorded.get(path)
        if not expected:
            continue
        try:
            stat = os.stat(path)
        except FileNotFoundError:
            raise InputChangedError(f"{path}: missing (an input of the render); {_INPUT_HINT}") from None
        key = (path, stat.st_size, stat.st_mtime_ns)
        found = _CHECKED.get(key) or sha256_file(path)
        if found != expected:
            raise InputChangedError(f"{path}: sha256 {found[:12]} differs from the {expected[:12]} recorded "
                                    f"when it was made (file changed or corrupt); {_INPUT_HINT}")
        _CHECKED[key] = found


_INPUT_HINT = ("delete it when `dotsim generate` writes it (DATASET/textures, DATASET/pattern.png), or "
               "rebuild the asset cache (`dotsim assets build`)")


def input_checksums(resources: SceneResources, pattern_file: str | os.PathLike, pattern_sha256: str
                    ) -> dict[str, str]:
    """path -> recorded sha256 of every file the scenes of `resources` may read."""
    sums = {str(pattern_file): pattern_sha256}
    sums.update({t.path: t.sha256 for t in resources.textures if t.sha256})
    sums.update({m.path: m.sha256 for m in resources.meshes if m.sha256})
    return sums


def _read_checksums(path: Path) -> dict[str, str]:
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {}
    return {k: v for k, v in data.items() if isinstance(v, str)} if isinstance(data, dict) else {}


def builtin_textures(folder: Path, split: str) -> tuple[TextureAsset, ...]:
    """Procedural reflectance textures (assets_manifest families) under folder/textures, made once.

    Each split draws its own seeds, so train and test never share a texture; files that exist are
    reused (same name = same family, index and split = same image) once they have the sha256
    recorded in folder/textures/checksums.json when they were made (InputChangedError names one
    that does not).
    """
    from assets_manifest.images import png_bytes, texture_from_image
    from assets_manifest.params import sample_params
    from assets_manifest.procedural_textures import TEXTURE_FAMILIES

    folder = Path(folder) / TEXTURE_DIR
    folder.mkdir(parents=True, exist_ok=True)
    record = folder / TEXTURE_CHECKSUMS
    recorded = _read_checksums(record)
    before = dict(recorded)
    textures = []
    for family_index, (family_name, family) in enumerate(sorted(TEXTURE_FAMILIES.items())):
        for k in range(BUILTIN_TEXTURES_PER_FAMILY):
            path = folder / f"{split}_{family_name}_{k}.png"
            if path.name not in recorded or not path.exists():
                rng = np.random.default_rng((SPLITS.index(split), family_index, k))
                image = family.make(sample_params({}, family.defaults, rng), rng)
                data = png_bytes(texture_from_image(image))
                if not path.exists():
                    atomic_write_bytes(path, data)
                recorded[path.name] = sha256_bytes(data)
            textures.append(TextureAsset(str(path), sha256=recorded[path.name]))
    if recorded != before:
        atomic_write_json(record, recorded)
    check_inputs({t.path: t.sha256 for t in textures}, [t.path for t in textures])
    return tuple(textures)


def cached_assets(config: Config, split: str) -> SceneResources:
    """Meshes and textures of `split` from the asset cache ([assets] cache_dir), without pattern
    fields, every file checked against the sha256 in the cache's index. Raises ConfigError naming
    the cache when it is not usable."""
    from assets_manifest.cache import AssetCacheError, load_asset_cache

    where = f"{config.source}: [assets] cache_dir = {config.assets.cache_dir!r}"
    try:
        cache = load_asset_cache(config.assets.cache_dir, split, verify=True)
    except AssetCacheError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if not cache.meshes:
        raise ConfigError(f"{where}: the {split} split has no meshes; allowed: a cache built with "
                          'meshes, or source = "primitives"')
    meshes = []
    for entry in cache.meshes:
        with np.load(entry.path) as arrays:
            extent = float(np.ptp(arrays["vertices"], axis=0).max())
        meshes.append(MeshAsset(entry.path, entry.id, extent, tuple(entry.scale_hint), entry.sha256))
    textures = tuple(TextureAsset(entry.path, tuple(entry.scale_hint), entry.sha256)
                     for entry in cache.textures)
    return SceneResources("", "", textures, tuple(meshes), cache.clutter_density)


def split_assets(config: Config, split: str, folder: str | os.PathLike) -> SceneResources:
    """Meshes and textures the scenes of `split` draw from (config.asset_split: the test scenes may
    draw the training assets), without pattern fields: the asset cache's
    when [assets] source = "cache" (nothing is written), else built-in primitives and the built-in
    textures under folder/textures. ConfigError naming the cache when it is not usable."""
    split = config.asset_split(split)
    if config.assets.source == "cache":
        return cached_assets(config, split)
    return SceneResources("", "", textures=builtin_textures(Path(folder), split))


def resources_in_folder(config: Config, split: str, folder: Path, pattern: DotPattern) -> SceneResources:
    """Pattern and assets of `split` with `pattern` and the built-in textures written under `folder`
    (a work folder, not a dataset) once: the pattern as folder/pattern_<sha256 prefix>.png, so
    configs with different patterns never share one. ConfigError naming the config when its asset
    cache cannot be used."""
    assets = split_assets(config, split, folder)
    pattern_path = folder / f"pattern_{pattern.sha256[:16]}.png"
    if not pattern_path.exists():
        pattern.save_png(pattern_path)
    return assets.with_pattern(str(pattern_path), pattern.sha256)
