"""Command-line options made from configuration dataclasses, so that a hyperparameter is one edit.

A field declared with :func:`demo.training.config.setting` and a ``help`` text becomes an option of
the command that fills its config: ``--field-name`` (or the field's ``flag``), the field's type, its
default (for a ``None`` default: ``show_default(name)``, else the field's ``unset`` text), and its
help. :func:`config_options` makes the parameters; :func:`with_options` adds them to a command's
signature, and the command receives their values as keyword arguments named after the fields.
"""

from __future__ import annotations

import dataclasses
import inspect
import types
import typing
from collections.abc import Callable, Sequence
from typing import Any

import typer


def _option_type(hint: Any) -> type:
    """``int`` for ``int | None``: what the command line parses."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        (kind,) = [a for a in typing.get_args(hint) if a is not type(None)]
        return kind
    return hint


def flag_of(f: dataclasses.Field) -> str:
    """The option that sets field ``f``."""
    return f.metadata.get("flag") or "--" + f.name.replace("_", "-")


def option_fields(config: type) -> list[dataclasses.Field]:
    """The fields of ``config`` that are command-line options (those with a ``help`` text)."""
    return [f for f in dataclasses.fields(config) if f.metadata.get("help")]


def config_options(config: type, show_default: Callable[[str], str | None] = lambda name: None,
                   prefix: str = "") -> list[inspect.Parameter]:
    """One keyword parameter (a ``typer.Option``) per option field of ``config``, in field order.

    ``show_default(name)``: the default shown for a field whose default is ``None`` (e.g. each
    policy's tuned value); ``prefix``: put before every help text (e.g. "dagger: ")."""
    hints = typing.get_type_hints(config)
    params = []
    for f in option_fields(config):
        kind = _option_type(hints[f.name])
        flag = flag_of(f)
        # A flag that is on (or unset) by default can be turned off: --flag/--no-flag.
        declared = f"{flag}/--no-{flag[2:]}" if kind is bool and f.default in (None, True) else flag
        shown: Any = True
        if f.default is None:
            shown = show_default(f.name) or f.metadata.get("unset") or False
        text = f.metadata["help"]
        text = prefix + text[:1].lower() + text[1:] if prefix else text
        option = typer.Option(f.default, declared, metavar=f.metadata.get("metavar"), help=text,
                              show_default=shown)
        params.append(inspect.Parameter(f.name, inspect.Parameter.KEYWORD_ONLY, default=option, annotation=kind))
    return params


def with_options(after: str, *groups: Sequence[inspect.Parameter]) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator: add ``groups`` of parameters to a command's signature after its parameter ``after``
    (typer reads the signature); the command takes them through ``**settings``."""

    def wrap(command: Callable[..., Any]) -> Callable[..., Any]:
        signature = inspect.signature(command, eval_str=True)
        own = [p.replace(kind=inspect.Parameter.KEYWORD_ONLY) for p in signature.parameters.values()
               if p.kind is not inspect.Parameter.VAR_KEYWORD]
        at = [p.name for p in own].index(after) + 1
        added = [p for group in groups for p in group]
        clash = {p.name for p in added} & {p.name for p in own}
        if clash:
            raise TypeError(f"{command.__name__}: options {sorted(clash)} are declared twice")
        command.__signature__ = signature.replace(parameters=[*own[:at], *added, *own[at:]])
        command.__annotations__ = {**typing.get_type_hints(command), **{p.name: p.annotation for p in added}}
        return command

    return wrap
