"""Harmonic balance: limit cycles as the zeros of a characteristic function ``Phi(A, w)``.

A loop whose nonlinear part is replaced by its describing function oscillates at amplitude ``A``
and frequency ``w`` when ``Phi(A, w) = 1 + L(jw, A) N(A) = 0`` (paper 002 eq. 6, Gibson 1963;
Slotine and Li 1991 section 5.4). This module finds *every* zero in a rectangle of ``(A, w)``:
``Phi`` is evaluated on a logarithmic grid, cells where both its real and imaginary parts change
sign are refined with :func:`scipy.optimize.root`, and each zero is classified by Loeb's criterion:
with ``Phi = X + jY``, the cycle is stable when

    dX/dA * dY/dw - dX/dw * dY/dA > 0

(Loeb 1956; Gelb and Vander Velde 1968 section 4.4). The sign follows from perturbing the
amplitude of a cycle and asking whether the growth rate ``sigma`` of ``s = sigma + jw`` it induces
is negative; it holds for ``Phi`` analytic in ``s``, e.g. a rational ``L`` times ``exp(-s Td)``.

:func:`lure_limit_cycles` is the classic single-nonlinearity loop (python-control's
``describing_function_response``); :mod:`tvcid.discovery.describing.actuator_loop` builds ``Phi`` for
an actuator hypothesis in the HWIL closed loop.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import root

from .errors import DescribingFunctionError
from .numeric import describing_function

__all__ = [
    "LimitCycle",
    "HarmonicBalanceResult",
    "solve_harmonic_balance",
    "lure_limit_cycles",
    "frequency_response",
]


@dataclass(frozen=True)
class LimitCycle:
    """One limit cycle predicted by harmonic balance.

    Attributes
    ----------
    amplitude : float
        First-harmonic amplitude of the loop's reference signal (the nonlinearity's input for a
        Lur'e loop; the actuator output ``delta`` for an actuator hypothesis).
    frequency : float
        Frequency (rad/s).
    stable : bool
        Loeb's criterion: True for a stable (observable) cycle.
    loeb_index : float
        ``A w (dX/dA dY/dw - dX/dw dY/dA)``; positive means stable.
    describing_function : complex
        The nonlinearity's describing function at the cycle.
    search_amplitude : float or None
        The amplitude variable the balance was solved in, when it is not ``amplitude`` (e.g. the
        dead zone's input for a loop with a band-pass feedback); Loeb's criterion is evaluated in
        that variable.
    """

    amplitude: float
    frequency: float
    stable: bool
    loeb_index: float
    describing_function: complex
    search_amplitude: float | None = None

    @property
    def frequency_hz(self) -> float:
        return self.frequency / (2.0 * np.pi)

    def to_dict(self) -> dict:
        return {
            "amplitude": self.amplitude,
            "frequency": self.frequency,
            "frequency_hz": self.frequency_hz,
            "stable": self.stable,
            "loeb_index": self.loeb_index,
            "describing_function": [self.describing_function.real, self.describing_function.imag],
            "search_amplitude": self.search_amplitude,
        }


@dataclass(frozen=True, eq=False)
class HarmonicBalanceResult:
    """Every harmonic-balance solution in a rectangle of amplitude and frequency.

    Attributes
    ----------
    limit_cycles : tuple of LimitCycle
        Sorted by amplitude.
    amplitudes, frequencies : ndarray
        The search grid (rad or the reference signal's unit; rad/s).
    characteristic : ndarray, complex, shape (n_amplitudes, n_frequencies)
        ``Phi`` on the grid.
    label : str
        What loop this is.
    caveat : str
        Where the first-harmonic approximation is known to be off for this loop.
    amplitude_name : str
        What the grid's amplitude is.
    """

    limit_cycles: tuple
    amplitudes: np.ndarray = field(repr=False)
    frequencies: np.ndarray = field(repr=False)
    characteristic: np.ndarray = field(repr=False)
    label: str = ""
    caveat: str = ""
    amplitude_name: str = "amplitude"

    @property
    def stable_cycles(self) -> tuple:
        return tuple(c for c in self.limit_cycles if c.stable)

    def to_dict(self) -> dict:
        return {
            "label": self.label,
            "caveat": self.caveat,
            "limit_cycles": [c.to_dict() for c in self.limit_cycles],
        }

    def plot(self, ax=None):
        """Zero contours of ``Re Phi`` and ``Im Phi`` over the grid; cycles at their crossings
        (filled: stable, open: unstable). Creates a figure only when ``ax`` is None."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        w, a = np.meshgrid(self.frequencies, self.amplitudes)
        ax.contour(w, a, self.characteristic.real, levels=[0.0], colors="C0")
        ax.contour(w, a, self.characteristic.imag, levels=[0.0], colors="C1", linestyles="--")
        ax.plot([], [], "C0", label="Re Phi = 0")
        ax.plot([], [], "C1--", label="Im Phi = 0")
        for c in self.limit_cycles:
            grid_amplitude = c.amplitude if c.search_amplitude is None else c.search_amplitude
            ax.plot(c.frequency, grid_amplitude, "ko", mfc="k" if c.stable else "w",
                    label=f"{'stable' if c.stable else 'unstable'} {c.amplitude:.3g} at {c.frequency:.3g} rad/s")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("frequency (rad/s)")
        ax.set_ylabel(self.amplitude_name)
        ax.set_title(self.label)
        ax.legend(fontsize="small")
        return ax


def _check_range(name, bounds):
    lo, hi = (float(b) for b in bounds)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0 < lo < hi):
        raise ValueError(f"{name} must be (low, high) with 0 < low < high (got {bounds!r})")
    return lo, hi


def _loeb_index(characteristic, a, w, step=1e-6):
    """``A w (X_A Y_w - X_w Y_A)`` by central differences in ``ln A`` and ``ln w``."""
    ea, ew = np.exp(step), np.exp(-step)
    d_a = (characteristic(a * ea, w) - characteristic(a * ew, w)) / (2 * step)
    d_w = (characteristic(a, w * ea) - characteristic(a, w * ew)) / (2 * step)
    return float(d_a.real * d_w.imag - d_w.real * d_a.imag)


def solve_harmonic_balance(
    characteristic,
    amplitude_range,
    frequency_range,
    describing_function_at=None,
    n_amplitudes=300,
    n_frequencies=400,
    label="",
    caveat="",
    tolerance=1e-9,
    amplitude_map=None,
    amplitude_name="amplitude",
) -> HarmonicBalanceResult:
    """All zeros of ``characteristic(A, w)`` in the rectangle, with their stability.

    Parameters
    ----------
    characteristic : callable
        ``Phi(A, w)``, complex, broadcasting over numpy arrays.
    amplitude_range, frequency_range : (float, float)
        Search rectangle (both searched on logarithmic grids).
    describing_function_at : callable, optional
        ``N(A, w)`` reported with each cycle.
    n_amplitudes, n_frequencies : int
        Grid size; a cycle is found when its cell is resolved (two zeros closer than a cell can
        be missed).
    tolerance : float
        Largest ``|Phi|`` accepted at a refined zero.
    amplitude_map : callable, optional
        ``(A, w) -> reported amplitude`` when the search variable ``A`` is not the amplitude to
        report; the search amplitude is kept in :attr:`LimitCycle.search_amplitude`. Loeb's sign
        carries over when the map increases with ``A``.
    amplitude_name : str
        Axis label of the search amplitude.
    """
    a_lo, a_hi = _check_range("amplitude_range", amplitude_range)
    w_lo, w_hi = _check_range("frequency_range", frequency_range)
    amplitudes = np.geomspace(a_lo, a_hi, int(n_amplitudes))
    frequencies = np.geomspace(w_lo, w_hi, int(n_frequencies))
    grid = np.asarray(characteristic(amplitudes[:, None], frequencies[None, :]), dtype=complex)
    re, im = np.sign(grid.real), np.sign(grid.imag)

    def changes(s):
        # strictly negative to strictly positive: a region where Phi is set to exactly 1
        # (no cycle can exist there) has a zero imaginary part but no zero of Phi on its edge
        corners = np.stack([s[:-1, :-1], s[1:, :-1], s[:-1, 1:], s[1:, 1:]])
        return (corners.min(axis=0) < 0) & (corners.max(axis=0) > 0)

    cells = np.argwhere(changes(re) & changes(im))

    bounds = np.log([[a_lo, w_lo], [a_hi, w_hi]]) + [[-2.0], [2.0]]

    def residual(z):
        z = np.clip(z, bounds[0], bounds[1])  # keep the solver where Phi is defined
        value = complex(np.asarray(characteristic(np.exp(z[0]), np.exp(z[1]))))
        return [value.real, value.imag]

    found = []
    for i, j in cells:
        start = [0.5 * np.log(amplitudes[i] * amplitudes[i + 1]), 0.5 * np.log(frequencies[j] * frequencies[j + 1])]
        sol = root(residual, start, method="hybr", options={"xtol": 1e-13})
        if not (np.all(np.isfinite(sol.x)) and np.all(sol.x >= bounds[0]) and np.all(sol.x <= bounds[1])):
            continue
        a, w = np.exp(sol.x)
        if not (a_lo <= a <= a_hi and w_lo <= w <= w_hi):
            continue
        if abs(complex(np.asarray(characteristic(a, w)))) > tolerance:
            continue
        if any(abs(a - fa) <= 1e-6 * fa and abs(w - fw) <= 1e-6 * fw for fa, fw in found):
            continue
        found.append((float(a), float(w)))
    cycles = []
    for a, w in sorted(found):
        index = _loeb_index(characteristic, a, w)
        n = complex(np.asarray(describing_function_at(a, w))) if describing_function_at else complex("nan")
        if amplitude_map is None:
            cycles.append(LimitCycle(a, w, bool(index > 0), index, n))
        else:
            reported = float(np.asarray(amplitude_map(a, w)))
            cycles.append(LimitCycle(reported, w, bool(index > 0), index, n, search_amplitude=a))
    cycles.sort(key=lambda c: c.amplitude)
    return HarmonicBalanceResult(tuple(cycles), amplitudes, frequencies, grid, label, caveat, amplitude_name)


def frequency_response(linear, frequency):
    """``H(jw)`` of ``linear``: a ``(num, den)`` pair of polynomial coefficients in ``s``
    (highest power first), or a callable of ``s`` (a python-control system is one)."""
    s = 1j * np.asarray(frequency, dtype=float)
    if callable(linear):
        return np.asarray(linear(s), dtype=complex)
    try:
        num, den = linear
        return np.polyval(np.atleast_1d(num), s) / np.polyval(np.atleast_1d(den), s)
    except (TypeError, ValueError):
        raise DescribingFunctionError(
            f"linear part {linear!r} is neither a (num, den) pair nor a callable of s"
        ) from None


def lure_limit_cycles(
    linear,
    nonlinearity,
    amplitude_range=(1e-3, 1e3),
    frequency_range=(1e-2, 1e2),
    **kwargs,
) -> HarmonicBalanceResult:
    """Limit cycles of the loop ``u = -N(e) ; e = H u`` with one nonlinearity: ``1 + H(jw) N(A) = 0``.

    Parameters
    ----------
    linear : (num, den) or callable of s
        The linear part ``H``.
    nonlinearity : element or callable
        An element of :mod:`tvcid.discovery.describing.elements` (its analytic describing function, or
        the numeric one for a :class:`~tvcid.discovery.describing.elements.Chain`), or a function
        ``N(A)`` returning the describing function.
    amplitude_range, frequency_range, **kwargs
        As in :func:`solve_harmonic_balance`; amplitudes are those of the nonlinearity's input.

    Examples
    --------
    python-control's documentation example (``H = 8/(s^3 + 2 s^2 + 2 s + 1)``, unit saturation):

    >>> from tvcid.discovery.describing.elements import Saturation
    >>> result = lure_limit_cycles(([8], [1, 2, 2, 1]), Saturation(1.0))
    >>> c = result.limit_cycles[0]
    >>> round(c.amplitude, 2), round(c.frequency, 3), c.stable
    (3.34, 1.414, True)
    """
    if hasattr(nonlinearity, "analytic_df"):
        def n_of(a):
            return describing_function(nonlinearity, a)
    elif callable(nonlinearity):
        n_of = nonlinearity
    else:
        raise DescribingFunctionError(f"nonlinearity {nonlinearity!r} is neither an element nor a function N(A)")

    def characteristic(a, w):
        return 1.0 + frequency_response(linear, w) * np.asarray(n_of(a))

    return solve_harmonic_balance(
        characteristic,
        amplitude_range,
        frequency_range,
        describing_function_at=lambda a, w: n_of(a),
        label=kwargs.pop("label", "Lur'e loop"),
        **kwargs,
    )
