"""Errors of the describing-function methods; every one is a ``ValueError`` naming the culprit."""
from __future__ import annotations

__all__ = [
    "DescribingFunctionError",
    "AmplitudeBelowDeadZoneError",
    "UnsupportedStructureError",
    "NoHarmonicBalanceSolution",
]


class DescribingFunctionError(ValueError):
    """Base class of the errors raised by :mod:`tvcid.discovery.describing`."""


class AmplitudeBelowDeadZoneError(DescribingFunctionError):
    """A measured amplitude leaves the dead zone's input inside the dead zone (no first harmonic)."""


class UnsupportedStructureError(DescribingFunctionError):
    """The hypothesis has an element or a placement the first-harmonic method cannot treat."""


class NoHarmonicBalanceSolution(DescribingFunctionError):
    """The harmonic-balance equations have no solution for the given data (not a numerical failure:
    the message says which condition cannot be met)."""
