"""Options declared once, on a dataclass: each field carries its command-line flags and
help, and :func:`with_options` gives a typer command one option per field. The fill
(``pipeline.fill.options``) and per-rig training (``pipeline.rig.options``) declare theirs
this way."""

from __future__ import annotations

import functools
import inspect
import typing
from dataclasses import field, fields

import typer

#: The longest text option recorded in a file and printed by a command (a name, a licence).
MAX_TEXT = 200


def one_line(text: str, limit: int = MAX_TEXT) -> bool:
    """Whether ``text`` is one line of printable text, not blank, at most ``limit`` characters:
    what a name or licence a command records (and later prints on one line) must be."""
    return bool(text.strip()) and text.isprintable() and len(text) <= limit


def path_like(name: str) -> bool:
    """Whether a model ``name`` (model.json's, rig.json's: what fills record and ``--model``
    finds) would read as a path: a separator in it, or ``.``/``..``."""
    return "/" in name or "\\" in name or name.strip() in (".", "..")


def names_a_glob(globs: str) -> bool:
    """Whether comma-separated file-name globs (``--include``, ``--data-include``) name at
    least one: an empty or blank one read every take."""
    return any(p.strip() for p in str(globs).split(","))


def option(default, *flags: str, help: str, **meta):
    """A dataclass field that is a command-line option: its default, flags, help, and any
    more ``meta`` (e.g. a path role) for the code that reads the fields."""
    return field(default=default, metadata={"flags": flags, "help": help, **meta})


def flags_of(cls) -> dict[str, str]:
    """Field name → its first command-line flag, for every field of the dataclass ``cls``."""
    return {f.name: f.metadata["flags"][0] for f in fields(cls)}


def job_args(options: dict, flags: dict[str, str], command: str) -> list[str]:
    """The command-line flags that give a farm job's ``options`` back to ``command`` (in
    ``flags``' order; a switch is its flag alone when set). Unknown names are a ValueError."""
    unknown = sorted(set(options) - set(flags))
    if unknown:
        raise ValueError(f"unknown {command} option(s): {', '.join(unknown)}")
    args: list[str] = []
    for key, flag in flags.items():
        v = options.get(key)
        if isinstance(v, bool):
            args += [flag] if v else []
        elif v is not None and v != "":
            args += [flag, str(v)]
    return args


def with_options(cls, lead: int = 1):
    """A decorator: the typer command gets every field of the dataclass ``cls`` as an option
    (after its first ``lead`` parameters) and takes them as one ``opts: cls`` keyword,
    unchecked (the command checks them first, so a bad one is one line naming the option)."""
    hints = typing.get_type_hints(cls)

    def decorate(command):
        sig = inspect.signature(command)
        added = [
            inspect.Parameter(
                f.name,
                inspect.Parameter.KEYWORD_ONLY,
                default=typer.Option(f.default, *f.metadata["flags"], help=f.metadata["help"]),
                annotation=hints[f.name],
            )
            for f in fields(cls)
        ]
        own = [
            p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for n, p in sig.parameters.items() if n != "opts"
        ]

        @functools.wraps(command)
        def run(**kw):
            return command(opts=cls(**{f.name: kw.pop(f.name) for f in fields(cls)}), **kw)

        run.__signature__ = sig.replace(parameters=own[:lead] + added + own[lead:])
        return run

    return decorate
