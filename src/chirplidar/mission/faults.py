"""Faults of a run outside the simulation, reported in one line.

A full disk, a missing permission or a failing file system while a chunk, the manifest or the
results file is written, and a lost ``--scheduler``, stop the run with a :class:`RunError`: one
line naming the file (or scheduler), how many chunks are finished and kept, and what to do
(``--resume``). A chunk folder with no finished chunk is removed, so that it does not block
the next run.
"""

from __future__ import annotations

import errno
import os
import shutil

#: Exit code of a run stopped by a file-system fault (disk full, permission, I/O error):
#: sysexits.h's EX_IOERR.
EXIT_IO = 74


class RunError(Exception):
    """A run stopped by a fault outside the simulation -- a full disk, a missing permission, a
    failing file system, the Dask scheduler lost -- as one line naming the file or address,
    what is kept and what to do. The finished (sealed) chunks are kept for ``--resume``.
    ``errno``: the OS error number, when there is one; ``exit_code``: the command line's
    (:data:`EXIT_IO` for file-system faults, 1 otherwise)."""

    def __init__(self, message: str, os_errno: int | None = None):
        super().__init__(message)
        self.errno = os_errno

    @property
    def exit_code(self) -> int:
        return EXIT_IO if self.errno else 1


class SchedulerLost(Exception):
    """The client lost its connection to the run's ``--scheduler`` (:func:`raise_run_fault`
    turns it into a :class:`RunError` that says which chunks are kept)."""


#: What to do about a file-system fault, by its error number.
FIXES = {errno.ENOSPC: "free some space", errno.EDQUOT: "free some space (disk quota)",
         errno.EACCES: "fix the permissions", errno.EPERM: "fix the permissions",
         errno.EROFS: "make the file system writable"}


def fix_for(exc: OSError) -> str:
    """What to do about the file-system fault ``exc`` (``free some space``, ...)."""
    return FIXES.get(exc.errno, "fix that")


def os_fault_text(exc: OSError) -> str:
    """``cannot write PATH: no space left on device`` (one line) of an OSError of a write."""
    where = exc.filename if exc.filename is not None else "a file"
    reason = os.strerror(exc.errno).lower()   # (h5py puts its error stack in exc.strerror)
    if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM):
        return f"cannot write {where}: {reason}"
    return f"{where}: {reason}"


def is_os_fault(exc: BaseException) -> bool:
    """An OSError of the file system (with an error number), not of the run's own logic."""
    return (isinstance(exc, OSError) and not isinstance(exc, FileExistsError)
            and isinstance(exc.errno, int) and exc.errno > 0)


def raise_run_fault(exc: BaseException, writer, n_chunks: int, scheduler) -> None:
    """After ``exc`` stopped a run (``writer``: its :class:`.results.ChunkWriter`): a chunk
    folder with no sealed chunk is removed (nothing to resume, and it would block the next
    run); a fault outside the simulation (file system, lost scheduler) is raised as a
    :class:`RunError` saying what is kept and what to do. Returns (for the caller to re-raise
    ``exc``) otherwise."""
    chunk_dir = writer.path_dir
    kept = sum(1 for i in range(n_chunks) if writer.is_ready(i)) if chunk_dir.is_dir() else 0
    if not kept:   # (unsealed chunk files would be computed again anyway)
        shutil.rmtree(chunk_dir, ignore_errors=True)
    if isinstance(exc, SchedulerLost):
        if kept:
            raise RunError(f"lost the Dask scheduler at {scheduler} after {kept} of {n_chunks} "
                           f"chunks; the finished chunks are kept in {chunk_dir}: run again "
                           "with --resume") from exc
        raise RunError(f"lost the Dask scheduler at {scheduler} before any of the {n_chunks} "
                       "chunks was finished: run again when it is back") from exc
    if _is_killed_worker(exc):
        task = str(getattr(exc, "task", "a chunk"))
        raise RunError(f"Dask gave up on {task}: every worker that ran it died (out of "
                       f"memory? lower --workers or survey.chunk_shots); {kept} of {n_chunks} "
                       f"chunks done and kept in {chunk_dir}: run again with --resume") from exc
    if is_os_fault(exc):
        fix = fix_for(exc)
        if kept:
            raise RunError(f"{os_fault_text(exc)}; {kept} of {n_chunks} chunks done and "
                           f"kept in {chunk_dir}: {fix}, then run again with --resume",
                           exc.errno) from exc
        raise RunError(f"{os_fault_text(exc)}; no chunk was finished, nothing is kept: {fix}, "
                       "then run again", exc.errno) from exc


def _is_killed_worker(exc: BaseException) -> bool:
    """Dask's KilledWorker: the scheduler gave up on a task whose workers all died."""
    return any(c.__name__ == "KilledWorker" and c.__module__.startswith("distributed")
               for c in type(exc).__mro__)
