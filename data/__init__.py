"""The bundled recordings and the papers' printed numbers (``README.md`` beside this file).

The folder ``data/`` of the checkout installs as the package ``tvcid.data``; :func:`path` is how
tvcid's code finds a file of it, in a checkout and in an installed wheel alike. ``bench/`` holds the
tests' fixtures and is not installed.
"""
from __future__ import annotations

from importlib.resources import files
from pathlib import Path

__all__ = ["path"]


def path(*parts: str) -> Path:
    """A bundled file, e.g. ``path("m000_closed_A.csv")`` or ``path("papers.json")``.

    Parameters
    ----------
    *parts : str
        The file's path inside the bundled folder, one component each.

    Returns
    -------
    pathlib.Path
        Where the file is on disk (it need not exist: the caller reads it and reports a missing
        file).

    Raises
    ------
    RuntimeError
        When tvcid is installed in a form that does not put its files on disk (a zip archive).
    """
    resource = files(__name__).joinpath(*parts)
    if not isinstance(resource, Path):
        raise RuntimeError(f"tvcid's bundled data are not files on disk ({resource!r}): install "
                           "tvcid from its wheel or its checkout")
    return resource
