"""The files a split's scenes refer to: the projector pattern, built-in textures, the asset cache.

One module for every front end, so they all sample scenes from the same files: `dotsim generate`
(generator/pipeline.py) keeps the pattern in the dataset (DATASET/pattern.png) and the built-in
textures in DATASET/textures; the Blender add-on (blender_addon/scene_source.py) keeps both in its
work folder (`resources_in_folder`). Everything is made once and reused: a file that exists is the
same image (names carry the split, the texture family and index, or the pattern's sha256).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from dotsim.file_io import atomic_write_bytes
from dotsim.pattern_store import make_pattern
from dotsim.patterns import DotPattern, PatternError
from generator.config import Config, ConfigError
from generator.sample_scene import MeshAsset, SceneResources, TextureAsset, build_rig
from generator.scene_spec import SPLITS

TEXTURE_DIR = "textures"
BUILTIN_TEXTURES_PER_FAMILY = 4


def config_pattern(config: Config) -> DotPattern:
    """The projector pattern of a config at its rig's projector resolution; ConfigError naming the
    config's [pattern] section when it cannot be made (a missing or unreadable file)."""
    rig = build_rig(config)
    try:
        return make_pattern(config.pattern, rig.projector.width, rig.projector.height)
    except PatternError as exc:
        raise ConfigError(f"{config.source}: [pattern]: {exc}") from None


def builtin_textures(folder: Path, split: str) -> tuple[TextureAsset, ...]:
    """Procedural reflectance textures (assets_manifest families) under folder/textures, made once.

    Each split draws its own seeds, so train and test never share a texture; files that exist are
    reused (same name = same family, index and split = same image).
    """
    from assets_manifest.images import png_bytes, texture_from_image
    from assets_manifest.params import sample_params
    from assets_manifest.procedural_textures import TEXTURE_FAMILIES

    folder = Path(folder) / TEXTURE_DIR
    folder.mkdir(parents=True, exist_ok=True)
    textures = []
    for family_index, (family_name, family) in enumerate(sorted(TEXTURE_FAMILIES.items())):
        for k in range(BUILTIN_TEXTURES_PER_FAMILY):
            path = folder / f"{split}_{family_name}_{k}.png"
            if not path.exists():
                rng = np.random.default_rng((SPLITS.index(split), family_index, k))
                image = family.make(sample_params({}, family.defaults, rng), rng)
                atomic_write_bytes(path, png_bytes(texture_from_image(image)))
            textures.append(TextureAsset(str(path)))
    return tuple(textures)


def cached_assets(config: Config, split: str) -> SceneResources:
    """Meshes and textures of `split` from the asset cache ([assets] cache_dir), without pattern
    fields. Raises ConfigError naming the cache when it is not usable."""
    from assets_manifest.cache import AssetCacheError, load_asset_cache

    where = f"{config.source}: [assets] cache_dir = {config.assets.cache_dir!r}"
    try:
        cache = load_asset_cache(config.assets.cache_dir, split)
    except AssetCacheError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    if not cache.meshes:
        raise ConfigError(f"{where}: the {split} split has no meshes; allowed: a cache built with "
                          'meshes, or source = "primitives"')
    meshes = []
    for entry in cache.meshes:
        with np.load(entry.path) as arrays:
            extent = float(np.ptp(arrays["vertices"], axis=0).max())
        meshes.append(MeshAsset(entry.path, entry.id, extent, tuple(entry.scale_hint)))
    textures = tuple(TextureAsset(entry.path, tuple(entry.scale_hint)) for entry in cache.textures)
    return SceneResources("", "", textures, tuple(meshes), cache.clutter_density)


def split_assets(config: Config, split: str, folder: str | os.PathLike) -> SceneResources:
    """Meshes and textures the scenes of `split` draw from, without pattern fields: the asset cache's
    when [assets] source = "cache" (nothing is written), else built-in primitives and the built-in
    textures under folder/textures. ConfigError naming the cache when it is not usable."""
    if config.assets.source == "cache":
        return cached_assets(config, split)
    return SceneResources("", "", textures=builtin_textures(Path(folder), split))


def resources_in_folder(config: Config, split: str, folder: str | os.PathLike) -> SceneResources:
    """Pattern and assets of `split` with the pattern and built-in textures written under `folder`
    once: the pattern as folder/pattern_<sha256 prefix>.png, so configs with different patterns
    never share one. ConfigError naming the config when its pattern or asset cache cannot be used."""
    folder = Path(folder)
    pattern = config_pattern(config)
    assets = split_assets(config, split, folder)
    pattern_path = folder / f"pattern_{pattern.sha256[:16]}.png"
    if not pattern_path.exists():
        pattern.save_png(pattern_path)
    return assets.with_pattern(str(pattern_path), pattern.sha256)
