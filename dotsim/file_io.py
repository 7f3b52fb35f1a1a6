"""Writing files so that readers see all or nothing, and sha256 checksums of bytes and files.

Every file dotsim writes for someone to read (datasets, caches, checkpoints, images, reports; not
scratch files in private temporary folders) goes through `atomic_writer`: the bytes go to
``.tmp-<name>-<pid>`` beside the final name, are flushed and fsync'ed, and the temporary file is
renamed into place (``os.replace``, atomic on POSIX), so a reader or a crash never leaves half a
file under the final name. A write that fails removes its temporary file; one that runs out of space raises
DiskFullError naming the file and the space it needed, one that cannot write at all (a read-only,
missing or unwritable folder) WriteError naming the file and the folder: one line each, which every
command prints as its error (commands/cli.py). A command that writes into a folder checks it first
(`check_writable_folder`), so nothing is written when the folder is unusable.

Standard library only, so Blender's own Python (generator/blender/run_in_blender.py) imports it
as well as the rest of dotsim.
"""

from __future__ import annotations

import concurrent.futures
import contextlib
import errno
import hashlib
import json
import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import BinaryIO

TMP_PREFIX = ".tmp-"
# Both mean "no room": a full filesystem, or the user's quota on it.
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT)


class DiskFullError(OSError):
    """A write ran out of space; the message names the file, the space it needed and the free space.

    An OSError with errno ENOSPC whose str() is the message alone (one line for a CLI to print);
    it survives pickling, so a worker process can raise it to its parent.
    """

    def __init__(self, message: str):
        super().__init__(errno.ENOSPC, message)

    def __str__(self) -> str:
        return self.strerror

    def __reduce__(self):
        return type(self), (self.strerror,)


class WriteError(OSError):
    """A file or folder could not be written for a reason other than space (a read-only filesystem,
    no permission, a missing folder, a file where a folder should be); str() is one line naming the
    path and what is allowed. Pickles, as DiskFullError."""

    def __init__(self, message: str, code: int = errno.EIO):
        super().__init__(code, message)

    def __str__(self) -> str:
        return self.strerror

    def __reduce__(self):
        return type(self), (self.strerror, self.errno)


def write_error(path: str | os.PathLike, error: OSError) -> WriteError:
    """The WriteError for a write of `path` that failed with `error` (not a full disk).

    >>> import errno
    >>> print(write_error("/d/out/a.png", OSError(errno.ENOENT, "No such file or directory")))
    /d/out/a.png: cannot write it: no folder /d/out; allowed: a path in an existing, writable folder
    """
    path = Path(path)
    folder = path.parent
    if error.errno == errno.ENOENT:
        why = f"no folder {folder}"
    elif error.errno == errno.ENOTDIR:
        why = f"{_existing(folder)} is a file, not a folder"
    elif error.errno == errno.EROFS:
        why = f"{folder} is on a read-only filesystem"
    elif error.errno in (errno.EACCES, errno.EPERM):
        why = f"no permission to write in {folder}"
    else:
        why = f"{error.strerror or error}"
    return WriteError(f"{path}: cannot write it: {why}; allowed: a path in an existing, writable folder",
                      error.errno or errno.EIO)


def _existing(path: Path) -> Path:
    """The nearest of `path` and its parents that exists."""
    while not path.exists() and path != path.parent:
        path = path.parent
    return path


def check_writable_folder(folder: str | os.PathLike, option: str) -> Path:
    """Make sure `folder` is (or can become) a writable directory, without leaving anything behind:
    the nearest existing one of it and its parents must be a directory in which a file can be
    created (probed with a temporary file: permission bits say nothing for root or a read-only
    mount). Returns the absolute path; WriteError naming `option` (the command's option, e.g.
    --out), the folder and the problem.
    """
    folder = Path(folder).absolute()
    existing = _existing(folder)
    if not existing.is_dir():
        raise WriteError(f"{option} {folder}: {existing} is a file, not a directory; allowed: a writable "
                         "directory", errno.ENOTDIR)
    try:
        with tempfile.TemporaryFile(dir=existing, prefix=".dotsim-write-test-"):
            pass
    except OSError as exc:
        raise WriteError(f"{option} {folder}: {existing} is not writable ({exc.strerror}); allowed: a "
                         "writable directory", exc.errno or errno.EIO) from None
    return folder


def make_folder(folder: str | os.PathLike) -> Path:
    """mkdir -p `folder`; WriteError naming it when that fails (a full disk: DiskFullError)."""
    folder = Path(folder)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        if is_disk_full(error):
            raise disk_full_error(folder, None) from None
        raise write_error(folder / ".", error) from None
    return folder


def temporary_name(final_name: str) -> str:
    """Name of the temporary sibling a write of `final_name` uses: ``.tmp-<final_name>-<pid>``.

    The pid suffix lets a resume tell leftovers of dead writers from files a live one still writes.

    Examples
    --------
    >>> temporary_name("index.json").startswith(".tmp-index.json-")
    True
    """
    return f"{TMP_PREFIX}{final_name}-{os.getpid()}"


def _size_text(n: int) -> str:
    for unit, scale in (("GB", 1 << 30), ("MB", 1 << 20), ("kB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n} bytes"


def disk_full_error(path: str | os.PathLike, needed: int | None, exact: bool = True) -> DiskFullError:
    """The DiskFullError for a write of `needed` bytes to `path` (`exact` False: at least that many;
    None: a write of unknown size, by a library that does not say)."""
    path = Path(path)
    try:
        free = f"{_size_text(shutil.disk_usage(path.parent).free)} free"
    except OSError:
        free = "free space unknown"
    if needed is None:
        amount = "more space"
    else:
        amount = _size_text(needed) if exact else f"more than {_size_text(needed)}"
    return DiskFullError(f"{path}: no space left on device: writing it needs {amount}, {free} on "
                         f"{path.parent}; free some space and rerun")


def is_disk_full(error: BaseException) -> bool:
    """True for an OSError meaning no space (ENOSPC, or EDQUOT: the quota is used up)."""
    return isinstance(error, OSError) and error.errno in _NO_SPACE


@contextlib.contextmanager
def atomic_writer(path: str | os.PathLike, size_hint: int = 0) -> Iterator[BinaryIO]:
    """Open a binary stream that becomes `path` only when the ``with`` block ends without error.

    size_hint: bytes the caller means to write, named in the DiskFullError when space runs out
    (otherwise the bytes written so far are named).
    """
    path = Path(path)
    tmp = path.with_name(temporary_name(path.name))
    try:
        with open(tmp, "wb") as stream:
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(tmp, path)
    except BaseException as error:
        written = _remove(tmp)
        if isinstance(error, DiskFullError | WriteError):
            raise
        if is_disk_full(error):
            raise disk_full_error(path, max(size_hint, written), exact=size_hint > 0) from None
        if isinstance(error, OSError) and error.filename in (str(tmp), str(path)):
            raise write_error(path, error) from None
        raise


def _remove(tmp: Path) -> int:
    """Remove a failed write's temporary file; its size (0 when there is none). Never raises: on a
    read-only filesystem even removing a file that is not there fails, and the error that stopped
    the write is the one to report."""
    try:
        size = tmp.stat().st_size
        tmp.unlink()
        return size
    except OSError:
        return 0


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> Path:
    """Write `data` to `path` atomically (see atomic_writer); returns the path."""
    path = Path(path)
    with atomic_writer(path, size_hint=len(data)) as stream:
        stream.write(data)
    return path


def json_bytes(obj) -> bytes:
    """Canonical JSON for files dotsim writes: sorted keys, 2-space indent, final newline.

    NaN and inf are refused (ValueError): they are not JSON and other readers reject them.

    Examples
    --------
    >>> json_bytes({"b": 1, "a": [1.5]})
    b'{\\n  "a": [\\n    1.5\\n  ],\\n  "b": 1\\n}\\n'
    """
    return (json.dumps(obj, indent=2, sort_keys=True, allow_nan=False) + "\n").encode()


class DuplicateKeyError(ValueError):
    """A JSON object (or YAML or FileStorage mapping) gives one key twice; `key` is that key."""

    def __init__(self, key):
        super().__init__(f"key {key!r} is given twice")
        self.key = key


def unique_keys(pairs) -> dict:
    """A mapping from (key, value) pairs, DuplicateKeyError when a key comes twice: the
    object_pairs_hook of every JSON file dotsim reads (json keeps the last of two silently, other
    readers the first).

    >>> json.loads('{"a": 1, "b": 2}', object_pairs_hook=unique_keys)
    {'a': 1, 'b': 2}
    >>> json.loads('{"a": 1, "a": 2}', object_pairs_hook=unique_keys)
    Traceback (most recent call last):
    dotsim.file_io.DuplicateKeyError: key 'a' is given twice
    """
    mapping = {}
    for key, value in pairs:
        if key in mapping:
            raise DuplicateKeyError(key)
        mapping[key] = value
    return mapping


def atomic_write_json(path: str | os.PathLike, obj) -> Path:
    """Write `obj` as canonical JSON (json_bytes) to `path` atomically; returns the path."""
    return atomic_write_bytes(path, json_bytes(obj))


def sha256_bytes(data: bytes) -> str:
    """Hex sha256 of `data`.

    Examples
    --------
    >>> sha256_bytes(b"")[:16]
    'e3b0c44298fc1c14'
    """
    return hashlib.sha256(data).hexdigest()


def sha256_file(path: str | os.PathLike) -> str:
    """Hex sha256 of a file's bytes, read in 1 MB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def map_in_threads(function: Callable, items: Iterable, threads: int) -> list:
    """[function(item) for item in items], in up to `threads` threads (1: in this one), in order.

    For work that releases the GIL (numpy, OpenEXR's codecs, hashing), so a frame's post-render
    and encoding use the cores a render used; the first error is raised as in a loop.
    """
    items = list(items)
    if threads <= 1 or len(items) <= 1:
        return [function(item) for item in items]
    with concurrent.futures.ThreadPoolExecutor(min(threads, len(items))) as pool:
        return list(pool.map(function, items))
