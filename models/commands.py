"""Replay an open-loop command known only as samples, as what it is.

A bench test's command is a square wave, a step or a smooth signal (a sine). Replayed by linear
interpolation, a sampled square wave ramps over one sample before each edge: at 1 kHz that moves
the edge by about half a sample, at 200 Hz by 2.5 ms, the size of the delay being identified.
So:

* a **piecewise-constant** command (few samples where it changes) is replayed as levels and edges
  (:meth:`OpenLoop.piecewise`). Each observed edge lies in ``(t[k-1], t[k]]``, where ``k`` is the
  first sample at the new level. When the edges are regular (a square wave: edge ``j`` at
  ``phase + j * half_period``), every edge narrows the common phase: the half period is scanned
  around a least-squares line through the edge samples and the edges placed at the centroid of the
  (phase, half period) values consistent with every interval. Where the intervals leave no sub-sample information (edges on a grid commensurate
  with the sampling) the latest feasible time is used, the zero-order hold, which is exact for the
  usual generator started on a sample. Irregular edges are held at their samples.
* anything else is a smooth command, read between samples by a cubic spline (not-a-knot). Linear
  interpolation lowers a sine by its chords, ``(2 pi f h)^2 / 12`` of the amplitude on average;
  the spline's error is of order ``(2 pi f h)^4``.
"""
from __future__ import annotations

import numpy as np

from .experiments import OpenLoop

__all__ = ["command_from_samples", "is_piecewise_constant", "regular_edge_times"]

#: A command whose value changes at no more than this fraction of its samples is piecewise constant.
PIECEWISE_FRACTION = 0.05


def is_piecewise_constant(u) -> bool:
    """True when ``u`` changes at few of its samples (a step, square wave or staircase)."""
    u = np.asarray(u, dtype=float)
    changes = np.count_nonzero(np.diff(u))
    return u.size > 2 and changes <= PIECEWISE_FRACTION * (u.size - 1)


def _edge_polygon(t, k):
    """The (phase, half period) pairs consistent with every observed edge of a regular sequence.

    Edge ``j`` lies in ``(lo_j, hi_j] = (t[k_j - 1], t[k_j]]``; the half period is scanned around
    its least-squares value and, for each, the phases with ``lo_j < phase + j*half <= hi_j`` form
    ``[phase_lo, phase_hi]`` (empty where ``phase_hi < phase_lo``). ``None`` for fewer than three
    edges or edges that are not regular.

    Returns
    -------
    (j, lo, hi, dt, halves, phase_lo, phase_hi)
    """
    if k.size < 3:
        return None
    j = np.arange(k.size)
    hi, lo = t[k], t[k - 1]
    dt = float(np.median(np.diff(t)))
    half, _ = np.polyfit(j, 0.5 * (lo + hi), 1)
    if not np.all(np.abs(np.diff(hi) - half) <= 1.5 * dt):
        return None
    halves = half + np.linspace(-2.0, 2.0, 801) * dt / max(k.size - 1, 1)
    phase_lo = np.max(lo[None, :] - j[None, :] * halves[:, None], axis=1)
    phase_hi = np.min(hi[None, :] - j[None, :] * halves[:, None], axis=1)
    return j, lo, hi, dt, halves, phase_lo, phase_hi


def regular_edge_times(t, k, unresolved="hold"):
    """Sub-sample edge times of a regular edge sequence, or ``None`` when it is not regular.

    Parameters
    ----------
    t : ndarray
        Sample times (s), uniform.
    k : ndarray of int
        Index of the first sample after each edge (``k >= 1``).
    unresolved : {"hold", "centre"}
        Where the edges go when the samples leave their phase free over a whole sample (every
        edge the same number of samples apart): at the first sample after each edge (a
        zero-order hold, exact for a command on the acquisition's clock) or at the centre of
        what the samples allow (least error on average for one that is not).
    """
    polygon = _edge_polygon(t, k)
    if polygon is None:
        return None
    j, lo, hi, dt, halves, phase_lo, phase_hi = polygon
    width = phase_hi - phase_lo
    feasible = width >= 0
    if not feasible.any():  # not a regular sequence after all: keep the samples
        return hi
    # the centroid of the feasible (phase, half) polygon
    half = float(np.sum(halves[feasible] * width[feasible]) / np.sum(width[feasible]))
    phase_lo = float(np.max(lo - j * half))
    phase_hi = float(np.min(hi - j * half))
    if phase_hi - phase_lo >= 0.99 * dt and unresolved == "hold":  # no sub-sample information
        phase = phase_hi
    else:
        phase = 0.5 * (phase_lo + phase_hi)
    return phase + j * half


def command_from_samples(t, u) -> OpenLoop:
    """The open-loop experiment replaying a command known as samples ``u`` at times ``t``.

    ``t`` is taken relative to its first sample (the experiment starts at 0).
    """
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    t = t - t[0]
    if not is_piecewise_constant(u):
        return OpenLoop.from_samples(t, u, interpolation="cubic" if u.size >= 4 else "linear")
    k = np.flatnonzero(np.diff(u)) + 1
    if k.size == 0:
        return OpenLoop.piecewise(np.zeros(0), np.array([u[0]]))
    edges = regular_edge_times(t, k)
    if edges is None:
        edges = t[k]
    levels = np.concatenate([[u[0]], u[k]])
    return OpenLoop.piecewise(edges, levels)
