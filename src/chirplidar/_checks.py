"""Argument validation for the physics kernels: ValueError naming the argument, never ``assert``.

One place for the generic checks; packages add only their own domain checks (optics: obstruction
ratio, grid size; atmosphere: outer scale).
"""

from __future__ import annotations

import numbers

import numpy as np


def real_scalar(name: str, value, *, allow_inf: bool = False) -> float:
    """A real scalar as float; NaN is always refused, infinity unless ``allow_inf``."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.ndarray)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 0:
        raise ValueError(f"{name} must be a scalar, got an array of shape {arr.shape}")
    v = float(arr)
    if np.isnan(v) or (not allow_inf and not np.isfinite(v)):
        raise ValueError(f"{name} must be finite, got {v!r}")
    return v


def positive(name: str, value) -> float:
    v = real_scalar(name, value)
    if v <= 0.0:
        raise ValueError(f"{name} must be > 0, got {v!r}")
    return v


def non_negative(name: str, value) -> float:
    v = real_scalar(name, value)
    if v < 0.0:
        raise ValueError(f"{name} must be >= 0, got {v!r}")
    return v


def real_array(name: str, value) -> np.ndarray:
    """A finite real array (0-d allowed) as float64; bool and complex dtypes are refused."""
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a real number, got {value!r}")
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError) as exc:  # ragged input
        raise ValueError(f"{name} must be a numeric array: {exc}") from None
    if arr.dtype == bool or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise ValueError(f"{name} must be real-valued, got dtype {arr.dtype}")
    arr = arr.astype(float)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def time_array(name: str, value) -> np.ndarray:
    """A finite 1-D real array of times (s) as float64."""
    t = real_array(name, value)
    if t.ndim != 1:
        raise ValueError(f"{name} must be a 1-D array of times, got shape {t.shape}")
    return t


def non_negative_array(name: str, value) -> np.ndarray:
    arr = real_array(name, value)
    if np.any(arr < 0.0):
        raise ValueError(f"{name} must be >= 0")
    return arr


def positive_array(name: str, value) -> np.ndarray:
    arr = real_array(name, value)
    if np.any(arr <= 0.0):
        raise ValueError(f"{name} must be > 0")
    return arr


def unit_interval_array(name: str, value) -> np.ndarray:
    arr = real_array(name, value)
    if np.any((arr < 0.0) | (arr > 1.0)):
        raise ValueError(f"{name} must lie in [0, 1]")
    return arr


def finite_array(name: str, value, dtype=float) -> np.ndarray:
    """A finite array of ``dtype`` (complex allowed when asked for)."""
    try:
        arr = np.asarray(value, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name} must be a numeric array: {exc}") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite (no NaN or inf)")
    return arr


def count(name: str, value) -> int:
    """A non-negative integer (a number of draws or shots)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be a non-negative integer, got {value!r}")
    if value < 0:
        raise ValueError(f"{name} must be >= 0, got {value}")
    return int(value)


def integer(name: str, value, minimum: int) -> int:
    """An integer >= ``minimum`` (grid sizes, sample counts, batches, pixels)."""
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral):
        raise ValueError(f"{name} must be an integer, got {value!r}")
    v = int(value)
    if v < minimum:
        raise ValueError(f"{name} must be >= {minimum}, got {v}")
    return v


def generator(name: str, value) -> np.random.Generator:
    if not isinstance(value, np.random.Generator):
        raise ValueError(
            f"{name} must be a numpy.random.Generator (no global random state), "
            f"got {type(value).__name__}"
        )
    return value


def out(arr: np.ndarray):
    """0-d results as Python floats, arrays unchanged."""
    return float(arr) if np.ndim(arr) == 0 else arr


def png_path(name: str, value):
    """``value`` as a ``pathlib.Path`` naming a ``.png`` file; ValueError naming ``name``."""
    import os
    from pathlib import Path

    try:
        path = Path(os.fspath(value))
    except TypeError:
        raise ValueError(f"{name}: expected a path, got {type(value).__name__}") from None
    if path.suffix.lower() != ".png":
        raise ValueError(f"{name}: must name a .png file, got {str(path)!r}")
    return path


def writable_file(option: str, path, suffix: str, *, make_parents: bool = False):
    """Check, before any work, that the file ``path`` can be written: ValueError, one line
    naming ``option``, when its name does not end in ``suffix``, it is a directory, its folder
    does not exist (with ``make_parents``: the nearest existing folder above it, where the
    missing ones would be made, is not a directory) or cannot be written. Writable means
    ``os.access`` says so and a probe file can be created (and is removed) there: ``os.access``
    says yes to root everywhere, also in /proc. Returns the path."""
    import os
    import tempfile
    from pathlib import Path

    path = Path(path)
    if path.suffix.lower() != suffix:
        raise ValueError(f"{option} {path}: the file name must end in {suffix}")
    if path.is_dir():
        raise ValueError(f"{option} {path}: is a directory; name a {suffix} file in it")
    folder = path.parent
    if make_parents:
        while not folder.exists() and folder != folder.parent:
            folder = folder.parent
    if not folder.is_dir():
        what = "is not a directory" if folder.exists() else "does not exist"
        raise ValueError(f"{option} {path}: {folder} {what}")
    if path.exists() and not os.access(path, os.W_OK):
        raise ValueError(f"{option} {path}: the file exists and cannot be written")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise ValueError(f"{option} {path}: cannot write in {folder} (permission denied)")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".chirplidar-check-"):
            pass
    except OSError as exc:
        raise ValueError(
            f"{option} {path}: cannot write in {folder} (creating a file "
            f"there fails: {exc.strerror or exc})"
        ) from None
    return path
