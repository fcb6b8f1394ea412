"""Argument checks for the scripting API: a misspelt keyword is bad input like any other, so it gets a
``ValueError`` naming the keyword and listing the accepted ones (Python's own answer is a TypeError
that names neither the alternatives nor, for ``**kwargs`` functions, anything at all)."""
from __future__ import annotations

import difflib
import functools
import inspect
from typing import Callable, Iterable

_NAMED = (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)


def reject_unknown(where: str, given: Iterable[str], accepted: Iterable[str]) -> None:
    """ValueError for the first keyword of ``given`` not in ``accepted``."""
    accepted = list(dict.fromkeys(accepted))
    for key in given:
        if key not in accepted:
            close = difflib.get_close_matches(key, accepted, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(f"{where}: unknown keyword {key!r}{hint}; accepted: {', '.join(accepted)}")


def checked(fn: Callable) -> Callable:
    """Decorator: unknown keywords, missing or surplus arguments of ``fn`` raise ValueError (see the module
    docstring).  Functions taking ``**kwargs`` check those keys themselves with ``reject_unknown``."""
    sig = inspect.signature(fn)
    named = [p.name for p in sig.parameters.values() if p.kind in _NAMED]
    open_kwargs = any(p.kind is inspect.Parameter.VAR_KEYWORD for p in sig.parameters.values())

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        if not open_kwargs:
            reject_unknown(fn.__name__, kwargs, named)
        try:
            sig.bind(*args, **kwargs)
        except TypeError as exc:
            raise ValueError(f"{fn.__name__}: {exc}; accepted: {', '.join(named)}") from None
        return fn(*args, **kwargs)

    return wrapper
