"""Python warnings raised by the core (a truncated log, a repaired stream) shown to CLI users
as one clean ``warning:`` line each, once, instead of the warnings module's two-line form."""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from contextlib import contextmanager


@contextmanager
def warnings_as_notes() -> Iterator[None]:
    """Collect warnings raised inside; print each distinct message once on stderr."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            yield
        finally:
            seen: set[str] = set()
            for w in caught:
                text = str(w.message)
                if text not in seen:
                    seen.add(text)
                    from uwval.cli.console import warn

                    warn(text)
