"""Read mission TOML files, apply ``--set`` overrides, validate.

Errors name the file and the dotted key path. Thesis names (``chrp.F2``) are accepted both in files
(as ``[chrp] F2 = ...``) and in ``--set``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any, Iterable, Mapping

from pydantic import ValidationError

from .aliases import THESIS_TO_KEY, resolve_key
from .keys import KeyIndex, model_keys
from .models import CHIRPED_SECTIONS, PULSED_SECTIONS, MissionConfig

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


class ConfigError(ValueError):
    """A configuration problem; the message names the file and key."""


PROJECT_KEYS: tuple[str, ...] = model_keys(MissionConfig)
ALL_KEYS: tuple[str, ...] = PROJECT_KEYS + tuple(THESIS_TO_KEY)
#: The mission's keys and thesis names; messages quote a key and add its thesis name.
MISSION_KEYS = KeyIndex(ALL_KEYS, "quoted", aliases={
    key: thesis for thesis, key in reversed(THESIS_TO_KEY.items())})


def _flatten(tree: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for k, v in tree.items():
        path = f"{prefix}{k}"
        if isinstance(v, Mapping):
            flat.update(_flatten(v, path + "."))
        else:
            flat[path] = v
    return flat


def unflatten(flat: Mapping[str, Any]) -> dict[str, Any]:
    """Nested tables from dotted keys: ``{"laser.power_w": 1}`` -> ``{"laser": {"power_w": 1}}``."""
    tree: dict[str, Any] = {}
    for path, v in flat.items():
        node = tree
        *parents, leaf = path.split(".")
        for p in parents:
            node = node.setdefault(p, {})
        node[leaf] = v
    return tree


def unknown_key_message(key: str, source: str) -> str:
    """``source: unknown key 'KEY' (did you mean: ...?)`` for a mission key."""
    return f"{source}: {MISSION_KEYS.unknown(key)}"


SCENE_PREFIX = "scene."


def _is_scene_override(key: str) -> bool:
    """Whether a dotted key changes the scene file (``scene.<scene key>``, not ``scene.file``):
    accepted here, validated by the scene loader (see :func:`scene_overrides`)."""
    return key.startswith(SCENE_PREFIX) and key != "scene.file" and len(key) > len(SCENE_PREFIX)


def is_known_key(key: str) -> bool:
    """Whether ``key`` (a project key, not a thesis name) is a mission key or a scene change."""
    return key in PROJECT_KEYS or _is_scene_override(key)


def scene_overrides(config: MissionConfig | str) -> dict[str, Any]:
    """The mission's changes to its scene file: scene dotted key -> value (empty if none), from
    a configuration or its TOML text (e.g. a results file's ``configuration`` attribute)."""
    flat = (_flatten(tomllib.loads(config)) if isinstance(config, str)
            else config_flat(config))
    return {k[len(SCENE_PREFIX):]: v for k, v in flat.items() if _is_scene_override(k)}


def _canonical(flat: Mapping[str, Any], source: str) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in flat.items():
        proj = resolve_key(key)
        if not is_known_key(proj):
            raise ConfigError(unknown_key_message(key, source))
        if proj in out:
            raise ConfigError(f"{source}: key '{proj}' given twice (once as '{key}')")
        out[proj] = value
    return out


def parse_set(assignment: str) -> tuple[str, Any]:
    """Parse ``KEY=VALUE``: VALUE is read as a TOML literal, else kept as a bare string."""
    if "=" not in assignment:
        raise ConfigError(f"--set '{assignment}': expected KEY=VALUE")
    key, raw = (s.strip() for s in assignment.split("=", 1))
    try:
        value = tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw
    return key, value


def build_config(flat: Mapping[str, Any], source: str) -> MissionConfig:
    try:
        return MissionConfig.model_validate(unflatten(flat))
    except ValidationError as err:
        raise ConfigError(MISSION_KEYS.message(err, source)) from None


#: Keys that name files, relative to the mission file that sets them.
PATH_KEYS = ("scene.file",)
#: The platform sections, of which a mission has one.
PLATFORM_SECTIONS = frozenset({"platform.uav", "platform.aircraft", "platform.orbit",
                               "platform.tle"})


#: The sections that describe the instrument (what ``instrument = "file.toml"`` and
#: ``--instrument`` bring in); the rest of a mission says where and when it flies.
INSTRUMENT_SECTIONS = frozenset((*CHIRPED_SECTIONS, *PULSED_SECTIONS, "channel", "apd", "effects",
                                 "receiver"))
#: Survey keys of the chirped receivers (their range gate and LO offsets), which a pulsed
#: instrument flown with ``--instrument`` drops: its digitizer's record is its window.
CHIRPED_SURVEY_KEYS = ("survey.range_window_m", "survey.doppler_compensation")


def is_instrument_key(key: str) -> bool:
    """Whether a dotted key belongs to the instrument (:data:`INSTRUMENT_SECTIONS`)."""
    return key.split(".", 1)[0] in INSTRUMENT_SECTIONS


def read_instrument_flat(path: str | Path, source: str) -> dict[str, Any]:
    """An instrument file's instrument keys (its other keys, such as a bench ``seed``, stay
    with the file). ``source`` names who asked for it, for the error."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"{source}: instrument file {path} does not exist")
    flat = {k: v for k, v in read_mission_flat(path).items() if is_instrument_key(k)}
    if not flat:
        raise ConfigError(f"{source}: {path} holds no instrument sections "
                          f"([{'], ['.join(sorted(INSTRUMENT_SECTIONS))}])")
    return flat


def with_instrument(flat: Mapping[str, Any], instrument: Mapping[str, Any]) -> dict[str, Any]:
    """The mission ``flat`` flown with another instrument: its instrument keys replaced, and
    its shot rate (``survey.prf_hz``) the new instrument's own; its ``survey.tier`` too, when
    the mission's tier does not fly the new instrument's kind (a pulsed instrument flies the
    pulsed tier only); a pulsed instrument drops the chirped receivers' survey keys
    (:data:`CHIRPED_SURVEY_KEYS`)."""
    from ..tiers.registry import tiers_flying

    out = {k: v for k, v in flat.items() if not is_instrument_key(k) and k != "survey.prf_hz"}
    if instrument:
        kind = "pulsed" if any(k.startswith("pulse.") for k in instrument) else "chirped"
        if out.get("survey.tier") not in tiers_flying(kind):
            out.pop("survey.tier", None)
        if kind == "pulsed":   # the chirped receivers' gate and LO: a pulsed one has neither
            for key in CHIRPED_SURVEY_KEYS:
                out.pop(key, None)
    return {**out, **instrument}


def read_mission_flat(path: str | Path, _seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The mission file as canonical dotted keys (thesis names translated).

    A top-level ``extends = "other.toml"`` (relative to this file) loads that file first and lets
    this one override it key by key, so a variant states only what differs and why; a
    ``[platform.X]`` section here replaces the parent's other platform sections. A top-level
    ``instrument = "file.toml"`` (relative to this file) flies that file's instrument
    (:data:`INSTRUMENT_SECTIONS`): the mission then states no instrument keys of its own.
    """
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: is a directory, not a mission file")
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read mission file ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise ConfigError(f"{path}: not a mission file (not UTF-8 text; a mission is a TOML "
                          "file)") from None
    try:
        tree = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    parent = tree.pop("extends", None)
    instrument = tree.pop("instrument", None)
    for name, value in (("extends", parent), ("instrument", instrument)):
        if value is not None and not (isinstance(value, str) and value.strip()):
            what = "a mission" if name == "extends" else "an instrument"
            raise ConfigError(f"{path}: '{name}' must name {what} file (a path in quotes), "
                              f"got {value!r}")
    flat = _canonical(_flatten(tree), str(path))
    if instrument is not None:
        own = sorted(k for k in flat if is_instrument_key(k))
        if own:
            raise ConfigError(f"{path}: names instrument = {instrument!r} and also sets "
                              f"{', '.join(own[:3])}{' ...' if len(own) > 3 else ''}: instrument "
                              "keys go in the instrument file (or one that extends it)")
        flat.update(read_instrument_flat((path.parent / instrument).resolve(),
                                         f"{path}: instrument = {instrument!r}"))
    if parent is None:
        return flat
    base_path = (path.parent / parent).resolve()
    if base_path in _seen:
        raise ConfigError(f"{path}: 'extends' loops back to {base_path}")
    if not base_path.is_file():
        raise ConfigError(f"{path}: extends = {parent!r}: {base_path} does not exist (the path "
                          "is relative to this file)")
    base = read_mission_flat(base_path, _seen + (base_path,))
    # File paths are relative to the file that names them: re-anchor the parent's to this one.
    for key in PATH_KEYS:
        value = base.get(key)
        if isinstance(value, str) and not Path(value).is_absolute():
            base[key] = os.path.relpath(base_path.parent / value, path.parent.resolve())
    # A child that flies another platform replaces the parent's: its [platform.X] drops the
    # parent's other platform sections (they are alternatives, only one may be present).
    chosen = {sec for sec in PLATFORM_SECTIONS if any(k.startswith(sec + ".") for k in flat)}
    if chosen:
        base = {k: v for k, v in base.items()
                if not any(k.startswith(sec + ".") for sec in PLATFORM_SECTIONS - chosen)}
    if instrument is not None:   # the named instrument replaces the parent's
        base = {k: v for k, v in base.items() if not is_instrument_key(k)}
    return {**base, **flat}


def load_mission(path: str | Path, overrides: Iterable[str] | Mapping[str, Any] = ()) -> MissionConfig:
    """Load and validate a mission file, applying ``--set`` style overrides.

    ``overrides`` is either ``["chrp.F2=300e6", ...]`` or a mapping of (thesis or project) key to value.
    The key ``instrument`` (:data:`INSTRUMENT_OVERRIDE`, ``--instrument``) flies another
    instrument file instead of the mission's own (:func:`with_instrument`).
    """
    flat = read_mission_flat(path)
    return apply_overrides(flat, overrides, str(path))


#: The override that flies another instrument file: ``--set instrument=PATH`` (what
#: ``--instrument PATH`` passes), applied before the others so that they change its keys.
INSTRUMENT_OVERRIDE = "instrument"


def apply_overrides(flat: Mapping[str, Any], overrides: Iterable[str] | Mapping[str, Any],
                    source: str) -> MissionConfig:
    if isinstance(overrides, (str, bytes)):
        raise ConfigError(f"overrides must be a list of KEY=VALUE strings or a mapping of key to "
                          f"value; got the string {overrides!r} (write [{overrides!r}])")
    items = list(overrides.items() if isinstance(overrides, Mapping)
                 else (parse_set(s) for s in overrides))
    merged = dict(flat)
    for key, value in items:
        if key == INSTRUMENT_OVERRIDE:
            if not (isinstance(value, str) and value.strip()):
                raise ConfigError(f"--instrument: expected the path of an instrument file, "
                                  f"got {value!r}")
            merged = with_instrument(merged, read_instrument_flat(value, "--instrument"))
    changed = []
    for key, value in items:
        if key == INSTRUMENT_OVERRIDE:
            continue
        proj = resolve_key(key)
        if not is_known_key(proj):
            raise ConfigError(unknown_key_message(key, "--set"))
        merged[proj] = value
        changed.append(proj)
    try:
        return build_config(merged, source)
    except ConfigError as exc:
        # A value given with --set is refused: name --set, not the file that holds the rest.
        msg = str(exc)
        if (source != "override" and msg.startswith(f"{source}: ")
                and any(f"'{k}'" in msg for k in changed)):
            raise ConfigError(f"--set: {msg[len(source) + 2:]}") from None
        raise


def config_with(config: MissionConfig, overrides: Mapping[str, Any]) -> MissionConfig:
    """A new validated config with dotted-key overrides (thesis names accepted)."""
    return apply_overrides(config_flat(config), overrides, "override")


def config_flat(config: MissionConfig) -> dict[str, Any]:
    """Dotted keys of a config; absent optional sections (None) are left out, not written as None."""
    return _flatten(config.model_dump(exclude_none=True))
