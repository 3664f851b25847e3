"""The dotted keys of a configuration schema, "did you mean" for an unknown one, and the one-line
message of a validation error: one implementation for mission files and scene files.

A :class:`KeyIndex` holds a schema's keys and the way its messages name them: mission messages
quote a key inside the sentence and add its thesis name (``'laser.power_w' (lsr.Po): ...``,
``unknown key 'chrp.F3' (did you mean: chrp.F2, ...?)``); scene messages lead with the key as a
label (``terrain.flat.height_m: ...``, ``terrain.resolution: unknown key (did you mean: ...)``).
"""

from __future__ import annotations

import difflib
import math
import typing
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

from pydantic import BaseModel, ValidationError
from pydantic.fields import FieldInfo

from .base import FieldError

#: At most this many problems are listed in a validation message (then "and N more").
MAX_LISTED_PROBLEMS = 6


def section_model(annotation) -> tuple[str, type[BaseModel]] | None:
    """``("model", M)`` for a section field ``M`` or ``M | None``; ``("dict", M)`` for a table of
    named sections ``dict[str, M]``; None for a value field."""
    if typing.get_origin(annotation) is dict:
        value = typing.get_args(annotation)[1]
        if isinstance(value, type) and issubclass(value, BaseModel):
            return "dict", value
    for ann in (annotation, *typing.get_args(annotation)):
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            return "model", ann
    return None


def iter_fields(model: type[BaseModel], prefix: str = "",
                entries: Mapping[str, Sequence[str]] | None = None
                ) -> Iterator[tuple[str, FieldInfo]]:
    """Every value field of ``model`` and its sections, depth first: (dotted key, field).

    entries: the allowed names of each table of named sections, by its dotted key (e.g.
    ``{"materials": MATERIAL_NAMES}``); each name gets the section's keys.
    """
    entries = entries or {}
    for name, info in model.model_fields.items():
        key = f"{prefix}{name}"
        sub = section_model(info.annotation)
        if sub is None:
            yield key, info
        elif sub[0] == "model":
            yield from iter_fields(sub[1], key + ".", entries)
        else:
            for entry in entries.get(key, ()):
                yield from iter_fields(sub[1], f"{key}.{entry}.", entries)


def model_keys(model: type[BaseModel], entries: Mapping[str, Sequence[str]] | None = None
               ) -> tuple[str, ...]:
    """The dotted keys of every value field of ``model`` (see :func:`iter_fields`)."""
    return tuple(key for key, _ in iter_fields(model, "", entries))


def one_line_message(source: str, missing: list[str], problems: list[str]) -> str:
    """A validation error in one line: the source, the missing keys together, then the other
    problems, ``; ``-separated, at most :data:`MAX_LISTED_PROBLEMS` of them."""
    if missing:
        problems = [f"missing key{'s' if len(missing) > 1 else ''} {', '.join(missing)}",
                    *problems]
    more = len(problems) - MAX_LISTED_PROBLEMS
    listed = problems[:MAX_LISTED_PROBLEMS] + ([f"and {more} more"] if more > 0 else [])
    return f"{source}: {'; '.join(listed)}"


@dataclass(frozen=True)
class KeyIndex:
    """A schema's keys (for suggestions) and how its messages name them.

    keys: every accepted dotted key (aliases included); aliases: key -> the other name shown
    beside it (the thesis name); style: ``"quoted"`` names a key inside the sentence,
    ``"label"`` leads with it.
    """

    keys: tuple[str, ...]
    style: Literal["quoted", "label"]
    aliases: Mapping[str, str] = field(default_factory=dict)

    def name(self, key: str) -> str:
        """How a message names ``key``."""
        if not key:
            return "(top level)"
        if self.style == "label":
            return key
        also = f" ({self.aliases[key]})" if key in self.aliases else ""
        return f"'{key}'{also}"

    def suggestions(self, key: str) -> list[str]:
        """Up to five known keys close to ``key``, else those with the same last component
        (``chrp.F3`` -> chrp.F2; ``F2`` -> chrp.F2)."""
        close = difflib.get_close_matches(key, self.keys, n=5, cutoff=0.6)
        if not close:
            leaf = key.rsplit(".", 1)[-1].lower()
            close = [k for k in self.keys if k.rsplit(".", 1)[-1].lower() == leaf][:5]
        return close

    def unknown(self, key: str) -> str:
        """The problem "unknown key", with suggestions."""
        close = self.suggestions(key)
        hint = f" (did you mean: {', '.join(close)}?)" if close else ""
        if self.style == "label":
            return f"{key}: unknown key{hint}"
        return f"unknown key '{key}'{hint}"

    def problem(self, error: Mapping) -> tuple[str, bool]:
        """One pydantic error as (text, whether it is a missing key)."""
        loc = [str(p) for p in error["loc"] if p != "__root__"]
        cause = (error.get("ctx") or {}).get("error")
        if isinstance(cause, FieldError):
            loc += [p for p in cause.key.split(".") if p]
            return f"{self.name('.'.join(loc))}: {cause.text}", False
        key = ".".join(loc)
        if error["type"] == "missing":
            return self.name(key), True
        if error["type"] == "extra_forbidden":
            return self.unknown(key), False
        msg = error["msg"].removeprefix("Value error, ")
        value = error.get("input")
        if isinstance(value, float) and math.isnan(value) and msg.startswith("Input should be"):
            msg = "not a number (NaN)"
        if isinstance(value, Mapping):
            # a section's own check names its keys; the section's whole contents would bury it
            return (msg if error["type"] == "value_error" else f"{self.name(key)}: {msg}"), False
        if not key:
            return msg, False
        return f"{self.name(key)}: {msg} (got {value!r})", False

    def message(self, err: ValidationError, source: str) -> str:
        """The whole error in one line: the source, the missing keys together, then each
        problem, ``; ``-separated (:func:`one_line_message`)."""
        missing, problems = [], []
        for error in err.errors():
            text, is_missing = self.problem(error)
            (missing if is_missing else problems).append(text)
        return one_line_message(source, missing, problems)
