"""The built-in configs, shipped inside the package: generator configs (default, structure_core,
kinect, tiny, bench_accuracy, table2) and training configs (train_tiny, train_cpu, train_gigadepth).

`--config NAME` names one of them; anything else is a path. A built-in config's relative paths
(its `cache_dir = "assets_cache"`) are resolved against the current directory, where `dotsim
assets build` writes the asset cache, since the folder the file lies in is inside the installed
package. `dotsim config show NAME` prints one to start a config of your own from.
"""

from __future__ import annotations

import os
from pathlib import Path

BUILTIN_DIR = Path(__file__).resolve().parent


TRAINING_PREFIX = "train_"  # training configs are named train_*; the others are generator configs


def builtin_names(kind: str | None = None) -> list[str]:
    """Names of the built-in configs (their file names without .toml): all, or only the "generator"
    or "training" ones."""
    names = sorted(path.stem for path in BUILTIN_DIR.glob("*.toml"))
    if kind is None:
        return names
    return [name for name in names if name.startswith(TRAINING_PREFIX) == (kind == "training")]


def builtin_path(name: str) -> Path | None:
    """The file of built-in config `name`, or None when there is none of that name."""
    path = BUILTIN_DIR / f"{name}.toml"
    return path if name in builtin_names() else None


def config_path(spec: str | os.PathLike) -> Path:
    """The file `--config SPEC` means: a built-in config's when SPEC is one's name, else SPEC itself."""
    return builtin_path(str(spec)) or Path(spec)


def relative_base(path: Path) -> Path:
    """The folder relative paths in config file `path` are resolved against: the current directory for
    a built-in config, the file's own folder for any other."""
    folder = Path(path).resolve().parent
    return Path.cwd() if folder == BUILTIN_DIR else folder
