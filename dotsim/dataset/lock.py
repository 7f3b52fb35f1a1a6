"""One writer per dataset folder on this machine: an advisory lock (fcntl) on DATASET/.writer.lock.

`writer_lock(DATASET, "dotsim generate")` is held by every command that writes a whole dataset
(`dotsim generate` without --no-seal, `--seal-only`, `dotsim verify --repair`, `dotsim capture
record`); a second one is refused at once with one line naming the holder's pid. The kernel drops
the lock when its holder exits, however it ends (kill -9 included), so a stale file locks nothing;
a writer that ends in order removes the file. Writers of disjoint scene ranges into one folder
(Slurm array tasks, `--no-seal`) take no lock; sealing (`seal_dataset`) stays right beside any
writer without one. The file starts with a dot, so it is no dataset-level file and never sealed;
on a filesystem without fcntl locks (or off POSIX) the lock is skipped.
"""

from __future__ import annotations

import contextlib
import errno
import os
from collections.abc import Iterator

from dotsim.dataset.layout import FormatError
from dotsim.file_io import disk_full_error, is_disk_full, make_folder, write_error

try:
    import fcntl
except ImportError:  # not POSIX: no advisory locks
    fcntl = None

LOCK_FILE = ".writer.lock"


class DatasetBusyError(FormatError):
    """Another process on this machine holds the dataset's writer lock."""


@contextlib.contextmanager
def writer_lock(dataset_dir: str | os.PathLike, what: str) -> Iterator[None]:
    """Hold DATASET's writer lock for the `with` block (creating DATASET when needed); `what` names
    the holder in the message a second writer gets. Raises DatasetBusyError when it is held."""
    root = make_folder(dataset_dir)
    if fcntl is None:
        yield
        return
    path = root / LOCK_FILE
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as error:  # a read-only or full filesystem: the one line every command prints
            raise (disk_full_error(path, None) if is_disk_full(error) else write_error(path, error)) from None
        try:
            fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            error = None
        except OSError as raised:
            error = raised
        if error is not None:
            holder = os.pread(fd, 200, 0).decode(errors="replace").strip() or "pid not recorded"
            os.close(fd)
            if error.errno in (errno.EACCES, errno.EAGAIN):
                raise DatasetBusyError(f"{root}: another writer holds this dataset ({holder}); wait for it "
                                       f"to end, or write elsewhere")
            break  # a filesystem without POSIX locks: go on unlocked
        try:
            if os.fstat(fd).st_ino == os.stat(path).st_ino:
                break  # locked the file that is there, not one its last holder just removed
        except FileNotFoundError:
            pass
        os.close(fd)
    if error is not None:
        yield
        return
    try:
        try:
            os.ftruncate(fd, 0)
            os.pwrite(fd, f"pid {os.getpid()}: {what}\n".encode(), 0)
        except OSError:  # a full disk: the lock holds all the same, the message lacks the pid
            pass
        yield
    finally:
        path.unlink(missing_ok=True)  # while still locked: a finished writer leaves no file behind
        os.close(fd)  # closing drops the lock
