"""One rule for every folder a command writes into: new, empty, or already of the command's own kind.

dotsim's commands write folders of six kinds, each recognised by the names it holds at its top level:

================  ==========================================  ==========================================
kind              written by                                  recognised by
================  ==========================================  ==========================================
dataset           ``generate`` (rendered scenes), ``capture   dataset.json, generate.json, .writer.lock,
                  import / record`` (real captures)           shard_NNNNN/, a dataset's index.json
export            ``export``                                  index.json of format dotsim-webdataset,
                                                              .progress.json (an unfinished export)
training run      ``train``                                   checkpoint.pt, tb/
eval              ``eval``                                    eval.md, eval.csv, errors/
predictions       ``infer``                                   NAME.exr written by infer (its header says
                                                              so), with NAME.png and NAME.ply beside it
asset cache       ``assets build``                            train/ or test/ holding an asset index.json
================  ==========================================  ==========================================

`check_output_folder` lets a command write into a folder only when it is new, empty (dotsim's own
temporaries, ``.tmp-*``, do not count: a killed run's rerun removes them), or of the command's own
kind (what else such a folder holds, e.g. a run's eval/ or a dataset's logs/, is its own business);
a folder that shows another kind, or none (a user's own files), is refused in one line that names
what was found, before anything is read or written, so nothing outside a command's own kind of folder
is ever changed. Whether a folder of the right kind fits the request (the same generate settings, the
same export plan, --resume for a run with a checkpoint) stays the command's own check. A dataset of
rendered scenes and one of real captures are told apart by their first scene.json: generate refuses
the one, capture the other.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import re
import shutil
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from dotsim.file_io import TMP_PREFIX, WriteError, check_writable_folder

DATASET = "dataset"
EXPORT = "export"
TRAINING_RUN = "training run"
EVAL = "eval"
PREDICTIONS = "predictions"
ASSET_CACHE = "asset cache"

# What a refusal says each kind is, and the command that writes it.
DESCRIPTIONS = {
    DATASET: "a dotsim dataset",
    EXPORT: "a `dotsim export` folder",
    TRAINING_RUN: "a `dotsim train` run",
    EVAL: "a `dotsim eval` folder",
    PREDICTIONS: "`dotsim infer` predictions",
    ASSET_CACHE: "an asset cache (`dotsim assets build`)",
}
# A dataset's two contents: generate writes the one, capture import / record the other.
RENDERED, CAPTURED = "rendered", "captured"

# The names that mark each kind (files or folders at the folder's top level; index.json is told by
# its content, below). They are the names the writers use: dotsim.dataset.layout (dataset.json,
# index.json), generator.engines.steps.RUN_FILE, dotsim.dataset.lock.LOCK_FILE, dotsim.shards.writer's
# PROGRESS_NAME, trainer.checkpoint.CHECKPOINT and its tb/, trainer.evaluate's eval.md, eval.csv, errors/.
_MARKERS = {
    "dataset.json": DATASET, "generate.json": DATASET, ".writer.lock": DATASET,
    ".progress.json": EXPORT,
    "checkpoint.pt": TRAINING_RUN, "tb": TRAINING_RUN,
    "eval.md": EVAL, "eval.csv": EVAL, "errors": EVAL,
}
_DATASET_SHARD = re.compile(r"shard_\d{5,}")
# What else a folder of a kind holds, named as its own in a refusal (they do not tell the kind alone: a
# user's pattern.png or shard-000000.tar is no export).
_MEMBERS = {DATASET: re.compile(r"pattern\.png|textures|logs|slurm"),
            EXPORT: re.compile(r"pattern\.png|SHA256SUMS|shard-\d{6}\.tar")}
_PREDICTION_SUFFIXES = (".exr", ".png", ".ply")
_ASSET_SPLITS = ("train", "test")
_SHOWN = 3  # names a refusal quotes


class OutputFolderError(WriteError):
    """A command's output folder holds something that is not the command's own kind (one line)."""

    def __init__(self, message: str):
        super().__init__(message, errno.EEXIST)


@dataclass(frozen=True)
class Contents:
    """What a folder holds: its kinds with the names that showed each (in order found), a dataset's
    contents (RENDERED, CAPTURED, or None before its first scene), and the names of no kind."""

    kinds: dict[str, list[str]]
    dataset: str | None
    others: list[str]

    @property
    def empty(self) -> bool:
        return not self.kinds and not self.others

    def text(self) -> str:
        """E.g. "a dotsim dataset of rendered scenes (dataset.json, shard_00000/)" or "other files
        (notes.txt)"; several parts joined by "and"."""
        parts = []
        for kind, names in self.kinds.items():
            what = DESCRIPTIONS[kind]
            if kind == DATASET and self.dataset:
                what += f" of {self.dataset} scenes"
            parts.append(f"{what} ({_names(names)})")
        if self.others:
            parts.append(f"{'other files' if self.kinds else 'files of no dotsim command'} "
                         f"({_names(self.others)})")
        return " and ".join(parts)


def _names(names: list[str]) -> str:
    more = f", ... {len(names) - _SHOWN} more" if len(names) > _SHOWN else ""
    return ", ".join(names[:_SHOWN]) + more


def _json_format(path: Path) -> str | None:
    """The "format" of the JSON object in `path`; "" for one without it; None when unreadable."""
    try:
        value = json.loads(path.read_bytes())
    except (OSError, ValueError):
        return None
    return str(value.get("format", "")) if isinstance(value, dict) else None


def _is_prediction(path: Path) -> bool:
    """An EXR `dotsim infer` wrote (dotsim.prediction_file's header attribute)."""
    try:
        from dotsim.prediction_file import prediction_source

        return prediction_source(path) is not None
    except Exception:  # noqa: BLE001 - an EXR OpenEXR cannot read is simply not a prediction
        return False


def _kind_of(path: Path) -> str | None:
    """The kind one top-level entry shows, or None."""
    name = path.name
    if name in _MARKERS:
        return _MARKERS[name]
    if name == "index.json" and path.is_file():
        fmt = _json_format(path)
        if fmt == "":
            return DATASET  # a dataset's index.json names no format (dotsim.dataset.layout.parse_index)
        if fmt and fmt.startswith("dotsim-webdataset"):
            return EXPORT
        return None
    if _DATASET_SHARD.fullmatch(name) and path.is_dir():
        return DATASET
    if name in _ASSET_SPLITS and path.is_dir():
        fmt = _json_format(path / "index.json")
        return ASSET_CACHE if fmt and fmt.startswith("dotsim-assets") else None
    return None


def folder_contents(folder: str | os.PathLike) -> Contents:
    """What `folder` holds (an empty Contents for a folder that does not exist or holds only dotsim's
    temporaries). Reads names, the index.json files and the headers of EXRs, nothing more."""
    folder = Path(folder)
    if not folder.is_dir():
        return Contents({}, None, [])
    kinds: dict[str, list[str]] = {}
    others = []
    for path in sorted(folder.iterdir()):
        if path.name.startswith(TMP_PREFIX):
            continue
        kind = _kind_of(path)
        shown = path.name + ("/" if path.is_dir() else "")
        if kind is None:
            others.append(shown)
        else:
            kinds.setdefault(kind, []).append(shown)
    for kind, members in _MEMBERS.items():
        if kind in kinds:
            kinds[kind] += [name for name in others if members.fullmatch(name.rstrip("/"))]
            others = [name for name in others if not members.fullmatch(name.rstrip("/"))]
    if not kinds and others:
        stems = {Path(name).stem for name in others if name.endswith(".exr")}
        predictions = [name for name in others if name.endswith(".exr") and _is_prediction(folder / name)]
        if predictions and all(name.endswith(_PREDICTION_SUFFIXES) and Path(name).stem in stems
                               for name in others) and len(predictions) == len(stems):
            kinds, others = {PREDICTIONS: others}, []
    return Contents(kinds, _dataset_contents(folder) if DATASET in kinds else None, others)


def _dataset_contents(folder: Path) -> str | None:
    from dotsim.dataset.scene_meta import holds_captures

    captured = holds_captures(folder)
    if captured is None:
        return RENDERED if (folder / "generate.json").is_file() else None
    return CAPTURED if captured else RENDERED


def check_output_folder(folder: str | os.PathLike, kind: str, option: str, command: str,
                        dataset: str | None = None) -> Path:
    """`folder` made absolute once it may be written by `command` (e.g. "dotsim generate"), which
    writes folders of `kind` (for DATASET: `dataset` says of which contents, RENDERED or CAPTURED):
    writable (dotsim.file_io.check_writable_folder), and new, empty, or of that kind alone. Raises
    WriteError, OutputFolderError naming `option`, the folder and what it holds.

    Examples
    --------
    >>> import tempfile
    >>> folder = Path(tempfile.mkdtemp())
    >>> _ = (folder / "notes.txt").write_text("mine")
    >>> try:
    ...     check_output_folder(folder, EXPORT, "-o", "dotsim export")
    ... except OutputFolderError as error:
    ...     print(*str(error).replace(str(folder), "DIR").split("; "), sep="\\n")
    -o DIR: holds files of no dotsim command (notes.txt)
    dotsim export writes only into a new or empty folder or a `dotsim export` folder
    """
    folder = check_writable_folder(folder, option)
    found = folder_contents(folder)
    own = DESCRIPTIONS[kind] + (f" of {dataset} scenes" if kind == DATASET and dataset else "")
    foreign = (found.others and not found.kinds) or set(found.kinds) - {kind} or (
        kind == DATASET and dataset and found.dataset not in (None, dataset))
    if foreign:
        raise OutputFolderError(f"{option} {folder}: holds {found.text()}; {command} writes only into a "
                                f"new or empty folder or {own}")
    return folder


@contextlib.contextmanager
def removed_if_failed(folder: str | os.PathLike, resumable: Callable[[Path], bool] = lambda folder: False
                      ) -> Iterator[None]:
    """Run the block; when it raises and `folder` was new or empty before it, remove what the block
    wrote there (the folder itself if it made it), unless `resumable(folder)` says that a rerun
    continues from it (a training run with a checkpoint). A failed command then leaves nothing that
    only looks like its output (a run's tb/ without a checkpoint); the error passes on."""
    folder = Path(folder)
    existed = folder.is_dir()
    before = set(folder.iterdir()) if existed else set()
    was_empty = folder_contents(folder).empty
    try:
        yield
    except BaseException:
        if was_empty and folder.is_dir() and not resumable(folder):
            if not existed:
                shutil.rmtree(folder, ignore_errors=True)
            else:
                for path in set(folder.iterdir()) - before:
                    if path.is_dir() and not path.is_symlink():
                        shutil.rmtree(path, ignore_errors=True)
                    else:
                        path.unlink(missing_ok=True)
        raise
