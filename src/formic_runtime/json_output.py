"""The ``--json`` output every command and node prints: one JSON object a line on stdout."""

from __future__ import annotations

import json
import sys


def emit_json(obj: dict) -> None:
    """``obj`` as one line on stdout (numbers JSON does not know, such as NumPy's, as floats;
    anything else, such as paths, as text), flushed so a parent process reads it at once."""
    sys.stdout.write(json.dumps(obj, default=_plain) + "\n")
    sys.stdout.flush()


def _plain(value) -> float | str:
    try:
        return float(value)
    except (TypeError, ValueError):
        return str(value)
