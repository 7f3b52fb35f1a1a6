"""assets_manifest: declared, reproducible, disjoint train/test asset sets and their built cache.

A manifest (TOML, see docs/ASSETS.md) lists the meshes and textures of one split: procedural
families expanded over seed ranges, user folders, and the photographs scikit-image ships.
`build_asset_cache` turns it into CACHE_DIR/<split>/ (npz meshes with UVs and normals, PNG
textures, index.json); `load_asset_cache` is what the generator reads.
"""

from assets_manifest.cache import AssetCache, AssetCacheError, AssetEntry, build_asset_cache, load_asset_cache
from assets_manifest.manifest import ManifestError, check_disjoint, load_manifest

__all__ = [
    "AssetCache",
    "AssetCacheError",
    "AssetEntry",
    "ManifestError",
    "build_asset_cache",
    "check_disjoint",
    "load_asset_cache",
    "load_manifest",
]
