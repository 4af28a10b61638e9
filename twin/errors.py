"""The one exception type users see: a one-line message naming what is wrong and what is allowed.

:func:`shown` quotes a user's value inside such a message.
"""
from __future__ import annotations

import json
import re


class TwinError(ValueError):
    """Bad input or an impossible request; ``str(err)`` is a complete one-line message."""


class InfeasibleDesign(TwinError):
    """The LMI design has no solution; the message names the requirement to relax."""


class PluginError(TwinError):
    """A controller or estimator (built-in or a user's) broke its contract
    (:mod:`twin.protocols`): could not be loaded, lacks a method, or returned a value of
    the wrong shape or a non-finite one. The message names the object and what was expected."""


QUOTE_LIMIT = 80  # characters of a value quoted in a message, by default
_LAYOUT = re.compile(r"\s*[^\S ]\s*")  # a run of white space holding a line break, a tab, ...


def shown(value, limit: int = QUOTE_LIMIT, *, as_json: bool = False) -> str:
    """``value`` quoted for a one-line message: its ``repr`` (its JSON with ``as_json``, for
    what was read from a JSON file), on one line, control characters escaped as ``repr``
    escapes them in a str, at most ``limit`` characters (a 10 MB string is not echoed back;
    a cut one ends in "…").

    A str's own line breaks are escaped (``'a\\nb'``); what a multi-line ``repr`` (a NumPy
    array's, a plugin's object's) puts between its lines is layout, and becomes one space.
    An object whose ``repr`` fails, or an int beyond Python's 4300-digit conversion, is
    named by its type: ``<a Foo>``.
    """
    try:
        text = json.dumps(value, ensure_ascii=False) if as_json else repr(value)
    except Exception:  # noqa: BLE001 -- a plugin's object whose repr fails is still named
        text = f"<a {type(value).__name__}>"
    if not text.isprintable():
        if not as_json:  # JSON without indent has no layout: all it holds is the value's
            text = _LAYOUT.sub(" ", text)
        text = "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)
    return text if len(text) <= limit else text[:limit - 1] + "…"


def raised_text(exc: BaseException, limit: int = 500) -> str:
    """What a plugin raised, for a one-line message: ``RuntimeError: boom``; an exit or an
    interrupt as what it is, ``SystemExit(0)`` or ``KeyboardInterrupt`` (:func:`ends_process`)."""
    if ends_process(exc):
        return f"{type(exc).__name__}({shown(exc.code)})" if isinstance(exc, SystemExit) else type(exc).__name__
    text = " ".join(str(exc).split())
    text = text if len(text) <= limit else text[:limit - 1] + "…"
    return f"{type(exc).__name__}: {text}"


def ends_process(exc: BaseException) -> bool:
    """True for what ends a process when nobody catches it (SystemExit, KeyboardInterrupt):
    raised by a plugin, a failure of that plugin, said with :data:`MAY_NOT_END`."""
    return isinstance(exc, (SystemExit, KeyboardInterrupt))


MAY_NOT_END = "a plugin may not end the process"


__all__ = ["InfeasibleDesign", "MAY_NOT_END", "PluginError", "QUOTE_LIMIT", "TwinError", "ends_process", "raised_text",
           "shown"]
