"""MkDocs hooks: the reference pages generated from the code at build time (never committed).

Generated pages (see ``GENERATED``):

* ``reference/cli.md`` from the command line's argparse parser;
* ``reference/configuration.md`` from the mission's pydantic models;
* ``reference/scene-files.md`` from ``scenes/README.md`` and the scene's pydantic models;
* ``reference/thesis-names.md`` from the thesis-name table of ``chirplidar.config.aliases``;
* ``index.md``, ``changelog.md`` and ``contributing.md`` from the repository's README.md,
  CHANGELOG.md and CONTRIBUTING.md (their ``docs/`` links rewritten for the site).

The site documents the repository it is built from: ``src/`` goes first on ``sys.path``.
"""

from __future__ import annotations

import argparse
import re
import sys
import types
import typing
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

# Where the generated pages read from: one line each to change when a name moves.
PARSER_FACTORY = ("chirplidar.cli", "build_parser")
MISSION_MODEL = ("chirplidar.config", "MissionConfig")
SCENE_MODEL = (("chirplidar.config", "SceneConfig"), ("chirplidar.mission.scene", "SceneConfig"))
THESIS_TABLE = ("chirplidar.config.aliases", "THESIS_TABLE")

#: Unit of a key from its name's suffix (longest suffix first): the project's naming rule.
UNIT_SUFFIXES = (
    ("_a_per_rthz", "A/√Hz"),
    ("_v_per_rthz", "V/√Hz"),
    ("_w_per_rthz", "W/√Hz"),
    ("_m_minus_2_3", "m^-2/3"),
    ("_rad_rms", "rad (rms)"),
    ("_per_m", "1/m"),
    ("_deg_s", "deg/s"),
    ("_mps", "m/s"),
    ("_ohm", "Ω"),
    ("_utc", "UTC (ISO 8601)"),
    ("_hz", "Hz"),
    ("_db", "dB"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_s", "s"),
    ("_m", "m"),
    ("_w", "W"),
    ("_v", "V"),
    ("_k", "K"),
    ("_a", "A"),
    ("_f", "F"),
)

# Sections of the mission that describe the transceiver (those the thesis tables cover).
TRANSCEIVER_SECTIONS = (
    "simulation",
    "system",
    "processing",
    "waveform",
    "laser",
    "modulator",
    "transmitter",
    "channel",
    "apd",
    "balanced",
    "pin",
    "heterodyne",
)


def _load(module: str, name: str):
    import importlib

    return getattr(importlib.import_module(module), name)


def md_escape(text: str) -> str:
    """Plain text safe inside a Markdown table cell."""
    text = re.sub(r"\s+", " ", str(text))
    for char, repl in (
        ("\\", "\\\\"),
        ("|", "\\|"),
        ("<", "&lt;"),
        (">", "&gt;"),
        ("*", "\\*"),
        ("_", "\\_"),
        ("[", "\\["),
        ("]", "\\]"),
        ("`", "\\`"),
    ):
        text = text.replace(char, repl)
    return text


def doc_to_md(text: str) -> str:
    """A docstring or description (reStructuredText-ish) as one escaped Markdown line: ``code``
    spans kept as code, Sphinx roles (``:mod:``, ``:func:``) dropped."""
    text = re.sub(r":[a-z]+:`([^`]+)`", r"``\\1``", " ".join(str(text).split()))
    parts = re.split(r"``(.+?)``", text)
    return "".join(f"`{p}`" if i % 2 else md_escape(p) for i, p in enumerate(parts))


def unit_of(name: str) -> str:
    for suffix, unit in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return unit
    return "–"


# ---------------------------------------------------------------------------------- CLI


def _help_text(action: argparse.Action, prog: str) -> str:
    if not action.help or action.help == argparse.SUPPRESS:
        return ""
    params = dict(vars(action), prog=prog)
    if params.get("choices") is not None:
        params["choices"] = ", ".join(map(str, params["choices"]))
    return action.help % params


def _action_row(action: argparse.Action, prog: str) -> str:
    names = (
        ", ".join(f"`{o}`" for o in action.option_strings) or f"`{action.metavar or action.dest}`"
    )
    if action.choices is not None and not isinstance(action, argparse._SubParsersAction):
        value = " \\| ".join(f"`{c}`" for c in action.choices)
    elif action.nargs == 0:
        value = "flag"
    else:
        value = f"`{action.metavar or action.dest.upper()}`"
        if action.nargs in ("+", "*"):
            value += " ..."
    if action.required:
        default = "required"
    elif action.nargs == 0 or action.default in (None, [], argparse.SUPPRESS):
        default = ""
    else:
        default = f"`{action.default}`"
    return f"| {names} | {value} | {default} | {md_escape(_help_text(action, prog))} |"


def _subcommands(parser: argparse.ArgumentParser):
    """(name, help, subparser) of every subcommand, in the parser's order."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            # Subcommands without help (hidden aliases such as `demo`) are not listed.
            helps = {a.dest: a.help for a in action._choices_actions}
            for name, sub in action.choices.items():
                if name in helps:
                    yield name, helps[name] or "", sub


def cli_page() -> str:
    parser = _load(*PARSER_FACTORY)()
    intro = (
        f"Generated at build time from `{'.'.join(PARSER_FACTORY)}()`: every subcommand of "
        "`chirplidar`, its options and their defaults, as `chirplidar COMMAND --help` "
        "prints them."
    )
    out = ["# Command line", "", intro, ""]
    if parser.description:
        out += [md_escape(parser.description), ""]
    commands = list(_subcommands(parser))
    out += ["| command | what it does |", "|---|---|"]
    out += [f"| [`{name}`](#{name}) | {md_escape(help_)} |" for name, help_, _ in commands]
    out.append("")
    for name, help_, sub in commands:
        out += [
            f"## {name}",
            "",
            md_escape(help_),
            "",
            "```text",
            sub.format_usage().strip(),
            "```",
            "",
            "| argument | value | default | meaning |",
            "|---|---|---|---|",
        ]
        out += [
            _action_row(a, sub.prog)
            for a in sub._actions
            if not isinstance(a, argparse._HelpAction)
        ]
        out.append("")
        if sub.epilog:
            out += [md_escape(sub.epilog), ""]
    if parser.epilog:
        out += ["## Notes", "", md_escape(parser.epilog), ""]
    return "\n".join(out)


# ------------------------------------------------------------------------ configuration


def _is_model(tp) -> bool:
    from pydantic import BaseModel

    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _type_name(tp) -> str:
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if tp is type(None):
        return "none"
    if origin is typing.Literal:
        return " \\| ".join(f'`"{a}"`' if isinstance(a, str) else f"`{a}`" for a in args)
    if origin in (typing.Union, types.UnionType):
        parts = [_type_name(a) for a in args if a is not type(None)]
        return " \\| ".join(parts)
    if origin in (tuple, list):
        if len(args) == 2 and args[1] is Ellipsis:
            return f"list of {_type_name(args[0])}"
        return "[" + ", ".join(_type_name(a) for a in args) + "]"
    if origin is dict:
        return f"table of {_type_name(args[1])}"
    if _is_model(tp):
        return f"[{tp.__name__}]"
    return getattr(tp, "__name__", str(tp))


def _default(field) -> str:
    from pydantic_core import PydanticUndefined

    if field.default_factory is not None:
        value = field.default_factory()
    elif field.default is PydanticUndefined:
        return "required"
    else:
        value = field.default
    if value is None:
        return "unset"
    if _is_model(type(value)):
        return "(section)"
    if isinstance(value, (tuple, list)):
        value = list(value)
    if isinstance(value, dict) and not value:
        return "`{}`"
    if isinstance(value, bool):
        return f"`{str(value).lower()}`"
    if isinstance(value, str):
        return f'`"{value}"`'
    return f"`{value}`"


def _models_in(tp) -> list:
    """The sub-models a field's annotation holds (a section, an optional section, a table)."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if _is_model(tp):
        return [tp]
    if origin is dict:
        return [a for a in args[1:] if _is_model(a)]
    return [m for a in args for m in _models_in(a)]


def _section_tables(model, prefix: str, aliases: dict[str, str], level: int) -> list[str]:
    """The table of a model's own keys, then one sub-section per nested model."""
    out: list[str] = []
    doc = (model.__doc__ or "").strip()
    if doc:
        out += [doc_to_md(doc), ""]
    fields, nested = [], []
    for name, field in model.model_fields.items():
        subs = _models_in(field.annotation)
        if subs:
            table = typing.get_origin(field.annotation) is dict
            nested.append((f"{name}.NAME" if table else name, subs))
        else:
            fields.append((name, field))
    # The thesis-name column only where a key of this table has one.
    thesis_col = any(f"{prefix}{name}" in aliases for name, _field in fields)
    leaves = []
    for name, field in fields:
        key = f"{prefix}{name}"
        thesis = (f"`{aliases[key]}` | " if key in aliases else " | ") if thesis_col else ""
        leaves.append(
            f"| `{key}` | {_type_name(field.annotation)} | {unit_of(name)} | "
            f"{_default(field)} | {thesis}{doc_to_md(field.description or '')} |"
        )
    if leaves:
        head = (
            "| key | type | unit | default | thesis name | description |"
            if thesis_col
            else "| key | type | unit | default | description |"
        )
        out += [head, "|---" * head.count(" | ") + "|---|", *leaves, ""]
    for name, subs in nested:
        for sub in subs:
            out += [f"{'#' * level} `[{prefix}{name}]`", ""]
            out += _section_tables(sub, f"{prefix}{name}.", aliases, min(level + 1, 6))
    return out


def _aliases() -> dict[str, str]:
    return {key: thesis for thesis, key, _unit, _table in _load(*THESIS_TABLE)}


def config_page() -> str:
    model = _load(*MISSION_MODEL)
    aliases = _aliases()
    intro = (
        f"Generated at build time from `{'.'.join(MISSION_MODEL)}` and its section models. "
        "Every key has its SI unit in its name (the *unit* column reads it from the suffix); "
        "physical quantities have no default (*required*: a mission file states them, "
        "usually through `extends`); unknown keys, inf and NaN are configuration errors. "
        "Set any key in a mission file's `[section]` or on the command line with "
        "`--set section.key=value`; the *thesis name* column gives the alias `--set` also "
        "accepts ([thesis names](thesis-names.md))."
    )
    out = ["# Mission configuration keys", "", intro, ""]
    top = []
    for name, field in model.model_fields.items():
        if not _models_in(field.annotation):
            top.append(
                f"| `{name}` | {_type_name(field.annotation)} | {unit_of(name)} | "
                f"{_default(field)} | {doc_to_md(field.description or '')} |"
            )
    if top:
        out += [
            "## Top-level keys",
            "",
            "| key | type | unit | default | description |",
            "|---|---|---|---|---|",
            *top,
            "",
        ]
    for name, field in model.model_fields.items():
        for sub in _models_in(field.annotation):
            optional = _default(field) != "required"
            out += [f"## `[{name}]`" + (" (optional)" if optional else ""), ""]
            out += _section_tables(sub, f"{name}.", aliases, 3)
    return "\n".join(out)


def _scene_model():
    for module, name in SCENE_MODEL:
        try:
            return _load(module, name), f"{module}.{name}"
        except (ImportError, AttributeError):
            continue
    raise ImportError(f"no scene model at any of {SCENE_MODEL}")


def scene_page() -> str:
    model, where = _scene_model()
    readme = (ROOT / "scenes" / "README.md").read_text(encoding="utf-8")
    body = readme.split("\n", 1)[1] if readme.startswith("# ") else readme
    intro = (
        "From the repository's `scenes/README.md`, followed by every scene key, generated "
        f"at build time from `{where}`."
    )
    out = ["# Scene files", "", intro, "", body.strip(), "", "## Scene keys", ""]
    top = []
    for name, field in model.model_fields.items():
        if not _models_in(field.annotation):
            top.append(
                f"| `{name}` | {_type_name(field.annotation)} | {unit_of(name)} | "
                f"{_default(field)} | {doc_to_md(field.description or '')} |"
            )
    out += ["| key | type | unit | default | description |", "|---|---|---|---|---|", *top, ""]
    for name, field in model.model_fields.items():
        for sub in _models_in(field.annotation):
            suffix = ".NAME" if typing.get_origin(field.annotation) is dict else ""
            out += [f"### `[{name}{suffix}]`", ""]
            out += _section_tables(sub, f"{name}{suffix}.", {}, 4)
    return "\n".join(out)


def thesis_names_page() -> str:
    table = _load(*THESIS_TABLE)
    model = _load(*MISSION_MODEL)
    intro = (
        f"Generated at build time from `{'.'.join(THESIS_TABLE)}`, the one table that serves "
        "`--set`, TOML loading and this page. The thesis's parameter names of Tables 4.1-4.9 "
        "and 4.11 are accepted wherever a project key is (`--set atm.Pattn=85`, or "
        "`[atm] Pattn = 85` in a mission file), and so are its values (`APD`, `COH`, `PIN`, "
        "`hom`, `het`, `FM`, `PN`, `on`, `off`). A misspelt key is an error listing the "
        "close matches."
    )
    out = [
        "# Thesis names and project keys",
        "",
        intro,
        "",
        "| thesis name | project key | thesis unit | table |",
        "|---|---|---|---|",
    ]
    out += [f"| `{t}` | `{k}` | {md_escape(u)} | {tab} |" for t, k, u, tab in table]
    covered = {k for _t, k, _u, _tab in table}
    rest = []
    for section in TRANSCEIVER_SECTIONS:
        field = model.model_fields.get(section)
        if field is None:
            continue
        for sub in _models_in(field.annotation):
            rest += [
                f"`{section}.{n}`"
                for n, f in sub.model_fields.items()
                if f"{section}.{n}" not in covered and not _models_in(f.annotation)
            ]
    if rest:
        out += [
            "",
            "## Keys the thesis tables do not hold",
            "",
            "The transceiver keys with no thesis name (the [configuration reference]"
            "(configuration.md) describes each): " + ", ".join(rest) + ".",
        ]
    return "\n".join(out) + "\n"


# ------------------------------------------------------------- repository Markdown files


def _repo_markdown(name: str) -> str:
    """A Markdown file of the repository root, its links rewritten for the site's root."""
    text = (ROOT / name).read_text(encoding="utf-8")
    text = re.sub(r"\]\(docs/", "](", text)
    text = re.sub(r"\]\((?:\./)?README\.md(#[^)]*)?\)", r"](index.md\1)", text)
    text = re.sub(r"\]\((?:\./)?CHANGELOG\.md(#[^)]*)?\)", r"](changelog.md\1)", text)
    text = re.sub(r"\]\((?:\./)?CONTRIBUTING\.md(#[^)]*)?\)", r"](contributing.md\1)", text)
    return text


GENERATED = {
    "index.md": lambda: _repo_markdown("README.md"),
    "changelog.md": lambda: _repo_markdown("CHANGELOG.md"),
    "contributing.md": lambda: _repo_markdown("CONTRIBUTING.md"),
    "reference/cli.md": cli_page,
    "reference/configuration.md": config_page,
    "reference/scene-files.md": scene_page,
    "reference/thesis-names.md": thesis_names_page,
}


def on_files(files, config):
    from mkdocs.structure.files import File

    for uri, make in GENERATED.items():
        existing = files.get_file_from_path(uri)
        if existing is not None:
            files.remove(existing)
        files.append(File.generated(config, uri, content=make()))
    return files


# The docstrings cross-reference in Sphinx's roles (:func:`x`, :class:`~a.b.C`); mkdocstrings
# renders them as text followed by code. Keep the code, with `~` showing the last name only.
_ROLE = re.compile(r":(?:func|class|mod|meth|attr|data|obj|exc):<code>(~?)([^<]*)</code>")


def on_page_content(html, page, config, files):
    return _ROLE.sub(lambda m: f"<code>{m[2].rsplit('.', 1)[-1] if m[1] else m[2]}</code>", html)
