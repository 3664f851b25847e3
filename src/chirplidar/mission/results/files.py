"""The file system under the results: one lock for the netCDF/HDF5 calls of this process,
atomic file writes (temp file, fsync, rename) and the OS error behind a failed write."""

from __future__ import annotations

import errno as _errno
import os
import shutil
import tempfile
import threading
from pathlib import Path

#: netCDF-C and HDF5 are not thread-safe: the results files of this process are opened, written
#: and read one at a time (e.g. the chunks of Dask workers that are threads of one process).
NETCDF_LOCK = threading.RLock()


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def _fsync_dir(directory: Path) -> None:
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


#: Free space (bytes) below which a failed write counts as the file system being full: HDF5
#: (through netCDF) reports ENOSPC only as "NetCDF: HDF error".
NEARLY_FULL_BYTES = 1 << 20


def _nearly_full(directory) -> bool:
    """Whether the file system of ``directory`` has (almost) no space left for this process."""
    try:
        return shutil.disk_usage(directory).free < NEARLY_FULL_BYTES
    except OSError:
        return False


def write_error(exc: BaseException, path, temp=None) -> OSError | None:
    """``exc``, raised while writing ``path`` (through its temp file ``temp``), as an OSError
    with the OS's error number and ``path`` as its file name -- disk full, quota, permission,
    read-only or failing file system -- or None when it is not such an error.

    netCDF and HDF5 turn a full disk into "NetCDF: HDF error" (a RuntimeError with no error
    number), and netCDF a file it cannot create on a full disk into EACCES: a library error,
    or a permission or I/O error in a folder this process may write in, while the file system
    has less than :data:`NEARLY_FULL_BYTES` free counts as ENOSPC. Call it before the temp
    file is removed (it holds the space)."""
    directory = Path(path).parent if str(Path(path).parent) else Path(".")
    full = OSError(_errno.ENOSPC, os.strerror(_errno.ENOSPC), str(path))
    if isinstance(exc, OSError) and exc.errno is not None and exc.errno > 0:  # netCDF's < 0
        if isinstance(exc, (FileExistsError, FileNotFoundError, IsADirectoryError,
                            NotADirectoryError, InterruptedError)):
            return None
        if exc.errno in (_errno.EACCES, _errno.EPERM, _errno.EIO) and _nearly_full(directory) \
                and os.access(directory, os.W_OK | os.X_OK):
            return full
        name = exc.filename
        if name is None or (temp is not None and Path(name) == Path(temp)):
            name = path
        return OSError(exc.errno, os.strerror(exc.errno), str(name))
    if isinstance(exc, (OSError, RuntimeError)) and _nearly_full(directory):
        return full
    return None


def write_atomic(path, write, *, overwrite: bool = False) -> Path:
    """Create ``path`` atomically: ``write(tmp)`` fills a temp file in the same directory, which
    is fsynced and renamed onto ``path`` (then the directory is fsynced).

    An existing ``path`` raises FileExistsError (and is untouched) unless ``overwrite``. On any
    failure (or interrupt) no partial file is left at ``path`` and the temp file is removed; a
    process killed mid-write leaves only the temp file ``.<name>.<random>.tmp``. A full disk,
    a missing permission or a failing file system raise an OSError naming ``path`` with the
    OS's error number (:func:`write_error`).
    """
    path = Path(path)
    tmp = atomic_begin(path, overwrite=overwrite)
    try:
        write(tmp)
    except BaseException as exc:
        err = write_error(exc, path, tmp)   # before the temp file goes (it holds the space)
        tmp.unlink(missing_ok=True)
        if err is not None:
            raise err from exc
        raise
    return atomic_commit(tmp, path, overwrite=overwrite)


def atomic_begin(path: Path, *, overwrite: bool) -> Path:
    """The temp file (created, usual permissions) that :func:`atomic_commit` renames onto
    ``path``; FileExistsError for an existing ``path`` unless ``overwrite``."""
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists (pass overwrite=True to replace it)")
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise ValueError(f"path: directory {directory} does not exist")
    try:
        fd, tmp_name = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
    except OSError as exc:   # e.g. a folder we may not write in, no inode left
        err = write_error(exc, path)
        if err is None:
            raise
        raise err from exc
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp makes 0600; give the usual permissions
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return tmp


def atomic_commit(tmp: Path, path: Path, *, overwrite: bool) -> Path:
    """fsync the finished temp file ``tmp`` and rename it onto ``path`` (see
    :func:`write_atomic`); the temp file is removed on any failure."""
    directory = path.parent if str(path.parent) else Path(".")
    try:
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        if overwrite:
            os.replace(tmp, path)
        else:
            try:
                os.link(tmp, path)  # atomic, never clobbers a file that appeared meanwhile
            except FileExistsError:
                raise FileExistsError(
                    f"{path} exists (pass overwrite=True to replace it)") from None
            except OSError:  # filesystem without hard links
                if path.exists():
                    raise FileExistsError(
                        f"{path} exists (pass overwrite=True to replace it)") from None
                os.replace(tmp, path)
            tmp.unlink(missing_ok=True)
        _fsync_dir(directory)
    except BaseException as exc:
        err = write_error(exc, path, tmp)
        tmp.unlink(missing_ok=True)
        if err is not None:
            raise err from exc
        raise
    return path


def write_bytes_atomic(path, data: bytes, *, overwrite: bool = True) -> Path:
    """Write a small file (e.g. a run manifest) atomically (:func:`write_atomic`)."""
    return write_atomic(path, lambda tmp: Path(tmp).write_bytes(data), overwrite=overwrite)
