"""Strict JSON: what every file tvcid writes uses, so that any JSON reader opens it.

Python's ``json`` writes ``NaN`` and ``Infinity`` tokens, which are not JSON; here a non-finite
number is written as ``null`` (a missing or undefined value: a cost that diverged, a bound that is
open), numpy scalars and arrays as plain numbers and lists.
"""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

__all__ = ["jsonable", "dumps", "write_json", "write_text_atomic"]


def jsonable(obj, default=None):
    """``obj`` with NaN and infinities as ``None``, numpy scalars and arrays as Python ones,
    tuples as lists; any other object through ``default`` (else ``TypeError``)."""
    if obj is None or isinstance(obj, (str, bool)):
        return obj
    if isinstance(obj, (float, np.floating)):
        return float(obj) if math.isfinite(obj) else None
    if isinstance(obj, (int, np.integer)):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, dict):
        return {k: jsonable(v, default) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [jsonable(v, default) for v in obj]
    if default is None:
        raise TypeError(f"{type(obj).__name__} is not JSON serialisable")
    return jsonable(default(obj))


def dumps(obj, default=None, indent=2) -> str:
    """Strict JSON of ``obj`` (:func:`jsonable`: non-finite numbers as ``null``)."""
    return json.dumps(jsonable(obj, default), indent=indent, allow_nan=False)


def write_json(path, obj, default=None, indent=2) -> Path:
    """Write ``obj`` to ``path`` as strict JSON (:func:`dumps`), with a final newline, atomically
    (:func:`write_text_atomic`)."""
    return write_text_atomic(path, dumps(obj, default, indent) + "\n")


def write_text_atomic(path, text) -> Path:
    """Write ``text`` to ``path`` (UTF-8) whole or not at all: into a file beside it, then renamed
    over it.

    An interruption (Ctrl-C, SIGTERM, a kill) while it writes leaves the earlier file as it was:
    a run resumed from that directory reads either one or the other, never a truncated file.
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, path)
    finally:
        if tmp.exists():  # not renamed: interrupted, or the write failed
            tmp.unlink()
    return path
