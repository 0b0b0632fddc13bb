"""Commands built from a declared table of options (issue 30).

typer builds a command from its function's signature; a command with many options would
need a function with many parameters. Instead the command is ``def cmd(**kw)`` and its
options are declared once, as a tuple of :class:`Opt` and :class:`Arg`;
:func:`declare_signature` turns the tuple into the signature typer reads. An option that
several commands take is declared once (in :mod:`uwval.cli.shared_options`) and reused,
so it has one name, kind, default and help everywhere.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Annotated, Any, Optional, TypeVar

import typer

F = TypeVar("F", bound=Callable[..., Any])

#: The default of an argument the user must give.
REQUIRED: Any = inspect.Parameter.empty


@dataclass(frozen=True)
class Opt:
    """One option: keyword (``dest``), flags, kind, default and help.

    ``kind`` is the Python type typer parses (str, float, int, bool for a flag, Path,
    list[str] for a repeatable option, tuple[float, float]); a default of None makes it
    optional. ``extra`` holds further typer.Option settings as (name, value) pairs
    (e.g. ``(("min", 0),)``)."""

    dest: str
    flags: tuple[str, ...]
    kind: Any
    default: Any
    help: str
    extra: tuple[tuple[str, Any], ...] = ()


@dataclass(frozen=True)
class Arg:
    """One positional argument: keyword, kind, help, default (:data:`REQUIRED` when the
    user must give it), and how ``--help`` shows it."""

    dest: str
    kind: Any
    help: str
    default: Any = REQUIRED
    metavar: str | None = None
    show_default: bool = True


def opt(dest: str, kind: Any, default: Any, help: str, *flags: str) -> Opt:
    """An :class:`Opt` whose flag, when none is given, is ``--dest`` with dashes."""
    return Opt(dest, flags or (f"--{dest.replace('_', '-')}",), kind, default, help)


def _annotation(item: Opt | Arg) -> Any:
    """The ``Annotated[type, typer.Option/Argument(...)]`` typer reads for ``item``."""
    kind: Any = item.kind if item.default is not None else Optional[item.kind]  # noqa: UP045
    if isinstance(item, Opt):
        return Annotated[kind, typer.Option(*item.flags, help=item.help, **dict(item.extra))]
    info: dict[str, Any] = {"help": item.help}
    if item.metavar is not None:
        info["metavar"] = item.metavar
    if not item.show_default:
        info["show_default"] = False
    return Annotated[kind, typer.Argument(**info)]


def signature(items: Iterable[Opt | Arg], context: bool = False) -> inspect.Signature:
    """The signature typer reads: keyword-only parameters in the order of ``items``
    (``--help`` lists them so), after ``ctx: typer.Context`` when ``context``."""
    kw = inspect.Parameter.KEYWORD_ONLY
    params = [inspect.Parameter("ctx", kw, annotation=typer.Context)] if context else []
    params += [
        inspect.Parameter(item.dest, kw, default=item.default, annotation=_annotation(item))
        for item in items
    ]
    return inspect.Signature(params, return_annotation=None)


def declare_signature(func: F, items: Iterable[Opt | Arg], context: bool = False) -> F:
    """Give ``func`` (a ``def cmd(**kw)``) the signature and annotations of ``items``, so
    that ``app.command()`` builds its options from them; returns ``func``."""
    sig = signature(items, context)
    func.__signature__ = sig  # type: ignore[attr-defined]
    func.__annotations__ = {p.name: p.annotation for p in sig.parameters.values()} | {
        "return": None
    }
    return func


def given_options(ctx: typer.Context, kw: dict[str, Any]) -> dict[str, Any]:
    """The options of ``kw`` that the user typed (not left at their default)."""
    return {
        k: v
        for k, v in kw.items()
        if getattr(ctx.get_parameter_source(k), "name", "DEFAULT") != "DEFAULT"
    }
