"""The chunk directory of a run: its manifest, the output's lock, and resuming a run.

A run writes its chunks into ``<out>.chunks/`` beside the output (e.g.
``outputs/greenland_uav.nc.chunks/``, :func:`chunk_dir_for`). The directory also holds
``manifest.json`` (written atomically before any chunk): mission file, resolved configuration
and its SHA-256, seed, tier, scene file and the SHA-256 of its text, the SHA-256 of the
terrain's DEM or mesh file, shot and chunk counts, software version and the ``date_created`` of
the run, so that a resumed run (``--resume``) writes the same global attributes as an
uninterrupted one. A run killed at any moment loses no finished chunk; ``--resume`` skips them,
removes temp files of killed writes and refuses a manifest that does not match the current run
(:func:`open_chunk_dir`). Each chunk is sealed (:class:`.results.ChunkWriter`). The output is
locked (``<out>.lock``, :func:`output_lock`) for the run's life.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import errno
import hashlib
import json
import os
import shutil
import sys
import time
import warnings
from pathlib import Path

from .. import __version__
from ..config.loader import ConfigError
from .faults import RunError, fix_for, is_os_fault, os_fault_text
from .results import ChunkWriter, write_bytes_atomic, write_error

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

MANIFEST_NAME = "manifest.json"
MANIFEST_FORMAT = "chirplidar-run-chunks/1"
LOCK_SUFFIX = ".lock"
# Manifest keys that identify a run: a resumed run must match them all.
_IDENTITY = ("format", "mission_file", "configuration_sha256", "seed", "tier", "scene_file",
             "scene_sha256", "input_files_sha256", "n_shots", "n_beams", "n_chunks",
             "chunk_shots", "software_version")


def sha256_text(text: str) -> str:
    """The SHA-256 (hex) of ``text`` in UTF-8."""
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def file_sha256(path) -> str:
    """The SHA-256 (hex) of the file ``path``, read in 4 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 22), b""):
            h.update(block)
    return h.hexdigest()


def chunk_dir_for(out) -> Path:
    """The chunk directory of a run writing ``out``: ``<out>.chunks`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".chunks")


def default_date_created() -> str:
    """Now (UTC, ISO 8601, seconds), or ``$SOURCE_DATE_EPOCH`` when set (reproducible files)."""
    env = os.environ.get("SOURCE_DATE_EPOCH")
    if env is not None and env.strip():
        try:
            t = int(env)
        except ValueError:
            raise ConfigError(f"SOURCE_DATE_EPOCH={env!r}: must be an integer number of "
                              "seconds since 1970-01-01 UTC") from None
    else:
        t = int(time.time())
    return _dt.datetime.fromtimestamp(t, _dt.timezone.utc).isoformat().replace("+00:00", "Z")



def build_manifest(mission_path: Path, config, scene, plan, config_toml: str) -> dict:
    """The manifest of a run (without its ``date_created``): what identifies it, and its
    resolved configuration ``config_toml``."""
    return {
        "format": MANIFEST_FORMAT,
        "mission_file": str(mission_path.resolve()),
        "configuration_sha256": sha256_text(config_toml),
        "seed": int(config.seed),
        "tier": config.survey.tier,
        "scene_file": str(Path(scene.path).resolve()),
        "scene_sha256": sha256_text(scene.text),
        # the terrain's own files (mesh, DEM): the mission's TLE and instrument files are in
        # the resolved configuration, the scene in its text
        "input_files_sha256": {str(p): file_sha256(p) for p in scene.input_files},
        "n_shots": plan.n_shots,
        "n_beams": plan.beams.n_beams,
        "n_chunks": plan.n_chunks,
        "chunk_shots": plan.chunk_shots,
        "software_version": __version__,
        "configuration": config_toml,
    }


def _flat_toml(text: str) -> dict:
    """``{"a.b": value}`` of TOML ``text`` ({} when it is not TOML)."""
    out = {}

    def walk(node, prefix):
        for k, v in node.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            else:
                out[f"{prefix}{k}"] = v
    try:
        walk(tomllib.loads(text), "")
    except (tomllib.TOMLDecodeError, AttributeError):
        return {}
    return out


def _manifest_differences(old: dict, new: dict) -> list[str]:
    """What differs between the manifest ``old`` of the chunks on disk and ``new`` of this run,
    one phrase per key (the configuration's differing keys named)."""
    diffs = []
    for key in _IDENTITY:
        if old.get(key) == new.get(key):
            continue
        if key == "configuration_sha256":
            a, b = _flat_toml(str(old.get("configuration", ""))), _flat_toml(new["configuration"])
            keys = sorted(k for k in set(a) | set(b)
                          if a.get(k) != b.get(k) and k not in ("seed", "survey.tier"))
            if keys:
                shown = ", ".join(f"{k} = {a.get(k, '(unset)')!r} there, "
                                  f"{b.get(k, '(unset)')!r} now" for k in keys[:5])
                more = f" and {len(keys) - 5} more" if len(keys) > 5 else ""
                diffs.append(f"configuration: {shown}{more}")
            elif old.get("seed") == new.get("seed") and old.get("tier") == new.get("tier"):
                diffs.append("configuration: the resolved configuration differs")
            continue
        if key == "scene_sha256":
            diffs.append("scene: the scene file's text differs")
            continue
        if key == "input_files_sha256":
            a, b = old.get(key) or {}, new.get(key) or {}
            changed = sorted(p for p in set(a) | set(b) if a.get(p) != b.get(p))
            if not changed:   # a manifest written before the key existed: no terrain files
                continue
            diffs.append(f"terrain file(s) {', '.join(changed)} changed on disk since the "
                         "chunks were computed")
            continue
        diffs.append(f"{key}: {old.get(key)!r} there, {new.get(key)!r} now")
    return diffs


def read_manifest(chunk_dir: Path) -> dict | None:
    """The manifest in ``chunk_dir`` (None without one); ConfigError when it is unreadable."""
    path = chunk_dir / MANIFEST_NAME
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: unreadable run manifest ({exc}); pass --overwrite to "
                          "discard the chunks in that directory") from None
    if not isinstance(data, dict) or not isinstance(data.get("date_created"), str):
        raise ConfigError(f"{path}: not a chirplidar run manifest; pass --overwrite to discard "
                          "the chunks in that directory")
    return data


def write_manifest(chunk_dir: Path, manifest: dict) -> None:
    """Write ``manifest`` into ``chunk_dir`` atomically."""
    text = json.dumps(manifest, indent=1, sort_keys=True) + "\n"
    write_bytes_atomic(chunk_dir / MANIFEST_NAME, text.encode("utf-8"), overwrite=True)


def remove_temporaries(chunk_dir: Path, out: Path) -> None:
    """Temp files of writes killed mid-way: chunks, the manifest and the results file."""
    ChunkWriter(chunk_dir).remove_temporaries()
    for pattern, where in ((f".{MANIFEST_NAME}.*.tmp", chunk_dir), (f".{out.name}.*.tmp",
                                                                      out.parent)):
        for p in where.glob(pattern):
            p.unlink(missing_ok=True)


# ---------------------------------------------------------------------------- resume
def check_chunk_dir(chunk_dir: Path, *, resume: bool, overwrite: bool) -> None:
    """Before any work: FileExistsError when ``chunk_dir`` holds an unfinished run, unless
    ``resume`` or ``overwrite``; ConfigError when this process cannot write in it."""
    if chunk_dir.exists() and not (resume or overwrite):
        raise FileExistsError(
            f"{chunk_dir} holds the chunks of an unfinished run: pass --resume to finish it or "
            "--overwrite to discard it (nothing was run)")
    if chunk_dir.is_dir():
        check_writable(chunk_dir, "--resume" if resume else "--overwrite")


def open_chunk_dir(chunk_dir: Path, out: Path, manifest: dict, *, resume: bool,
                   date_created: str | None) -> str:
    """Make ``chunk_dir`` ready for the run of ``manifest`` (:func:`build_manifest`) writing
    ``out``; returns the run's ``date_created``.

    With ``resume``, an existing chunk directory must belong to this run (its manifest
    matches; ConfigError otherwise) and its ``date_created`` is kept; temp files of killed
    writes are removed. Without it, an existing one is discarded. A new chunk directory gets
    the manifest, with ``date_created`` or, without it, :func:`default_date_created`.
    """
    old = None
    if chunk_dir.exists() and resume:
        old = _manifest_to_resume(chunk_dir, manifest, date_created)
        if old is not None:
            date_created = old["date_created"]
        remove_temporaries(chunk_dir, out)
    elif chunk_dir.exists():   # overwrite: discard the unfinished run (and its results temp)
        remove_temporaries(chunk_dir, out)
        shutil.rmtree(chunk_dir)
    if old is None:
        if date_created is None:
            date_created = default_date_created()
        _start_chunk_dir(chunk_dir, {**manifest, "date_created": date_created})
    return date_created


def _manifest_to_resume(chunk_dir: Path, manifest: dict, date_created: str | None) -> dict | None:
    """The manifest of the run in ``chunk_dir`` (None: neither a manifest nor a chunk there);
    ConfigError unless it is the run of ``manifest`` (and ``date_created``, when given)."""
    if not chunk_dir.is_dir():
        raise ConfigError(f"{chunk_dir}: exists and is not a chunk directory")
    old = read_manifest(chunk_dir)
    if old is None and ChunkWriter(chunk_dir).completed_chunks():
        raise ConfigError(f"{chunk_dir}: chunk files without a {MANIFEST_NAME}: cannot tell "
                          "which run they belong to; pass --overwrite to discard them")
    if old is not None:
        diffs = _manifest_differences(old, manifest)
        if date_created is not None and date_created != old["date_created"]:
            diffs.append(f"date_created: {old['date_created']!r} there, "
                         f"{date_created!r} now")
        if diffs:
            raise ConfigError(f"{chunk_dir}: --resume: the chunks there belong to a "
                              f"different run ({'; '.join(diffs)}); rerun with the same "
                              "settings, or pass --overwrite to discard them")
    return old


def _start_chunk_dir(chunk_dir: Path, manifest: dict) -> None:
    """Create ``chunk_dir`` with ``manifest``; on a fault, no chunk folder is left to block a
    rerun, and a file-system fault is a :class:`.faults.RunError`."""
    try:
        chunk_dir.mkdir(exist_ok=True)
        write_manifest(chunk_dir, manifest)
    except BaseException as exc:   # e.g. a full disk
        if chunk_dir.is_dir() and not ChunkWriter(chunk_dir).completed_chunks():
            shutil.rmtree(chunk_dir, ignore_errors=True)
        if is_os_fault(exc):
            raise RunError(f"{os_fault_text(exc)}; no chunk was computed: "
                           f"{fix_for(exc)}, then run again", exc.errno) from exc
        raise


# ---------------------------------------------------------------------------- lock
def check_writable(directory: Path, what: str) -> None:
    """ConfigError, before any work, unless this process may create files in ``directory``."""
    if os.access(directory, os.W_OK | os.X_OK):
        return
    try:
        read_only = bool(os.statvfs(directory).f_flag & os.ST_RDONLY)
    except (OSError, AttributeError):
        read_only = False
    reason = os.strerror(errno.EROFS if read_only else errno.EACCES).lower()
    raise ConfigError(f"{what}: cannot write in {directory}: {reason} (nothing was run)")


def _process_alive(pid: int) -> bool:
    """Whether process ``pid`` of this host runs."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # someone else's process: alive
        return True
    return True


@contextlib.contextmanager
def output_lock(out: Path):
    """Hold ``<out>.lock`` (this process's pid, host and start) for the run's life: a second
    run on the same output is refused at once, naming the holder; a lock left by a process of
    this host that no longer runs is taken over with a warning."""
    import socket

    lock = out.with_name(out.name + LOCK_SUFFIX)
    me = {"pid": os.getpid(), "host": socket.gethostname(),
          "since": _dt.datetime.now(_dt.timezone.utc).replace(microsecond=0).isoformat()}
    for attempt in (0, 1):
        try:
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            break
        except FileExistsError:
            try:
                holder = json.loads(lock.read_text(encoding="utf-8"))
                pid, host = int(holder["pid"]), str(holder["host"])
            except (OSError, ValueError, KeyError, TypeError):
                holder, pid, host = {}, -1, ""
            stale = host == me["host"] and pid > 0 and not _process_alive(pid)
            if not stale or attempt:
                who = (f"pid {pid} on {host} since {holder.get('since', '?')}" if holder
                       else "an unknown process")
                raise FileExistsError(f"{out}: another run is writing it ({who}; lock "
                                      f"{lock}); wait for it to finish, or delete the lock if "
                                      "that run is gone") from None
            warnings.warn(f"{lock}: taking over the lock of pid {pid}, which no longer runs",
                          stacklevel=3)
            lock.unlink(missing_ok=True)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            json.dump(me, f)
    except BaseException as exc:   # e.g. a full disk: no lock left behind to block the next run
        lock.unlink(missing_ok=True)
        err = write_error(exc, lock)
        if err is not None and is_os_fault(err):
            raise RunError(f"{os_fault_text(err)}; nothing was run: {fix_for(err)}, then run "
                           "again", err.errno) from exc
        raise
    try:
        yield lock
    finally:
        lock.unlink(missing_ok=True)
