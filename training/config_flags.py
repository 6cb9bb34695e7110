"""Command-line flags generated from the config dataclasses (``parallel_skills.config``): one flag
per field, dotted for the nested learner configs (``--num_envs 64``, ``--scheduler.n_step 10``,
``--new_skill.samples_per_insert 32``), its help the comment above or beside the field in the source.

Plain ``argparse`` generated from ``dataclasses.fields``, no new dependency: tyro or
simple-parsing would add one, and their errors are usage blocks where the project's contract is
one ``error:`` line and exit code 2 (``training.cli.Parser``). A flag's text is read by the field's
type (``text_value``; a list is comma-separated, ``--scheduler.skill_lengths 10,20``; a boolean
``true`` / ``false``) and judged by the dataclass alone: the flag's type function builds the
class's default with that one value, so ``__post_init__`` runs, and its ``FieldError`` becomes
``argument --FLAG: expected <what is allowed>, got '<text>'``. Rules that relate several fields
(a plain ValueError there) are left to the config that the given flags make together
(``training.run`` sets them with ``config.from_dict``).

Every generated flag defaults to None, "not given": ``given(args, names)`` is what the user set,
so the recipe fills only the rest (``config.resolve(given=...)``) and ``--resume`` can reject the
given flags that conflict with a run's config.json.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import inspect
import io
import json
import textwrap
import tokenize

from parallel_skills.config import FieldError, field_types, from_json_value

METAVARS = {int: "INT", float: "FLOAT", bool: "true|false", str: "STR", tuple: "INT,INT,..."}


@functools.lru_cache(maxsize=None)
def field_comments(cls) -> dict:
    """``{field name: its comment}`` from ``cls``'s source for the fields that have one: the ``#``
    lines right above the field and the one at its end, joined (backquotes dropped); {} where the
    source cannot be read."""
    try:
        source = textwrap.dedent(inspect.getsource(cls))
    except (OSError, TypeError):
        return {}
    lines = source.splitlines()
    trailing = {tok.start[0]: tok.string for tok in tokenize.generate_tokens(io.StringIO(source).readline)
                if tok.type == tokenize.COMMENT and lines[tok.start[0] - 1].strip() != tok.string}
    names = {f.name for f in dataclasses.fields(cls)}
    out, above = {}, []
    for number, line in enumerate(lines, 1):
        text = line.strip()
        if text.startswith("#"):
            above.append(text)
            continue
        name = text.split(":", 1)[0].strip()
        if line.startswith("    ") and not line.startswith("     ") and name in names:
            parts = above + ([trailing[number]] if number in trailing else [])
            if parts:
                out[name] = " ".join(p.lstrip("#").strip() for p in parts).replace("``", "")
        above = []
    return out


def flag_names(cls, prefix: str = "") -> list:
    """The dotted names of ``cls``'s fields, nested configs' fields in their place
    (``["recipe", ..., "scheduler.skill_lengths", ...]``)."""
    out = []
    for name, (kind, _) in field_types(cls).items():
        out += flag_names(kind, f"{prefix}{name}.") if dataclasses.is_dataclass(kind) else [prefix + name]
    return out


def text_value(kind, text: str):
    """A flag's text as field type ``kind`` reads it: a string as it is; a list split at commas
    (``10,20`` or ``[10, 20]``); else JSON (``64``, ``3e-4``, ``true``); what does not read stays
    text, for the dataclass to reject with its own message."""
    if kind is str:
        return text
    if kind is tuple:
        return from_json_value(tuple, [text_value(int, t.strip()) for t in text.strip("[]() ").split(",")])
    try:
        return from_json_value(kind, json.loads(text.lower() if kind is bool else text))
    except ValueError:
        return text


def field_parser(cls, name: str):
    """The argparse type of field ``name`` of ``cls``: its text read (``text_value``), then checked
    by the class (its default with this one value; a FieldError of this field is the error)."""
    kind = field_types(cls)[name][0]

    def parse(text: str):
        value = text_value(kind, text)
        try:
            dataclasses.replace(cls(), **{name: value})
        except FieldError as e:
            if e.name == name:
                raise argparse.ArgumentTypeError(f"expected {e.allowed}, got {text!r}") from None
        except ValueError:  # a rule relating fields: the config of all the given flags checks it
            pass
        return value

    return parse


def field_help(cls, name: str, default, note: str = "") -> str:
    """A flag's help: the field's comment, ``note``, and the default (argparse's ``%`` escaped)."""
    parts = [field_comments(cls).get(name, ""), note]
    if default is not None:
        shown = ",".join(map(str, default)) if isinstance(default, tuple) else json.dumps(default)
        parts.append(f"(default {shown})")
    return " ".join(p for p in parts if p).replace("%", "%%")


def add_config_flags(parser, base, prefix: str = "", notes=None, computed=()) -> list:
    """Add a flag for every field of the config ``base`` (a dataclass instance: the defaults the
    help shows) to ``parser``, one argument group per config class; nested configs' flags dotted.
    ``notes``: ``{dotted name: text}`` appended to a flag's help; ``computed``: the dotted names
    whose default the caller computes (their note says how; no default shown). Returns the names."""
    cls, notes = type(base), notes or {}
    title = f"{prefix[:-1]} ({cls.__name__})" if prefix else cls.__name__
    group = parser.add_argument_group(title, (cls.__doc__ or "").split("\n\n")[0].replace("``", ""))
    names = []
    for name, (kind, _) in field_types(cls).items():
        dotted, default = prefix + name, getattr(base, name)
        if dataclasses.is_dataclass(kind):
            names += add_config_flags(parser, default, f"{dotted}.", notes, computed)
            continue
        group.add_argument(f"--{dotted}", dest=dotted, default=None, type=field_parser(cls, name),
                           metavar=METAVARS.get(kind, "VALUE"),
                           help=field_help(cls, name, None if dotted in computed else default, notes.get(dotted, "")))
        names.append(dotted)
    return names


def given(args, names) -> dict:
    """``{dotted name: value}`` of the flags among ``names`` that were given (not None)."""
    values = vars(args)
    return {n: values[n] for n in names if values.get(n) is not None}


def flag_text(value) -> str:
    """A flag's value as it would be typed (a list comma-separated, a boolean true / false)."""
    if isinstance(value, tuple):
        return ",".join(map(str, value))
    return json.dumps(value) if isinstance(value, bool) else str(value)
