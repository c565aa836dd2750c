"""The weak (integral) form of the actuator equation, built here and handed to pysindy optimizers.

Strong-form SINDy on numerical derivatives of ``delta`` fails on this actuator (40-90 %
errors in ``delta'''``). Multiplying the equation by compact test functions ``phi`` and integrating
by parts moves every derivative onto ``phi``: ``int phi delta''' = -int phi''' delta``,
``int phi delta'' = int phi'' delta``, ``int phi delta' = -int phi' delta`` (the weak SINDy of
Messenger and Bortz, 2021). No measured signal is differentiated numerically. Terms built from
the (possibly discontinuous) command are integrated on a finer quadrature grid; the play operator
and the sign of the velocity act on a smoothed ``delta``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view
from numpy.polynomial import polynomial as P
from scipy.signal import savgol_coeffs, savgol_filter

from tvcid.models.cycle_reading import white_noise_sd

from .library import command_jumps, delayed_command

__all__ = [
    "BumpTestFunctions",
    "PreparedSignals",
    "RecordingTooShortError",
    "estimate_noise",
    "prepare_signals",
    "weak_integrals",
]


#: Fine-quadrature step (s) for a command without jumps.
SMOOTH_COMMAND_STEP = 1e-3


class RecordingTooShortError(ValueError):
    """A recording holds no whole test-function support after the delay margin."""


@dataclass(frozen=True)
class BumpTestFunctions:
    """Compact polynomial test functions ``phi(t) = (1 - ((t - c)/h)^2)^p`` on ``|t - c| <= h``.

    With ``p > 3``, ``phi`` and its first three derivatives vanish at the support's ends, so three
    integrations by parts leave no boundary terms (Messenger and Bortz 2021, eq. 2.3).

    Parameters
    ----------
    half_width : float
        ``h`` (s).
    power : int
        ``p`` (>= 4).
    overlap : float
        Fraction of a support shared by neighbouring test functions (centres ``2h(1-overlap)``
        apart).
    """

    half_width: float = 0.025
    power: int = 6
    overlap: float = 0.5

    def __post_init__(self):
        if not (self.half_width > 0 and math.isfinite(self.half_width)):
            raise ValueError(f"test-function half_width must be > 0 (got {self.half_width!r})")
        if self.power < 4:
            raise ValueError(f"test-function power must be >= 4 (got {self.power})")
        if not 0 <= self.overlap < 1:
            raise ValueError(f"test-function overlap must be in [0, 1) (got {self.overlap})")

    def derivative(self, order, offsets):
        """``d^order phi / dt^order`` at ``offsets = t - c`` (s)."""
        coeffs = P.polypow([1.0, 0.0, -1.0], self.power)
        coeffs = P.polyder(coeffs, order) if order else coeffs
        s = np.asarray(offsets, dtype=float) / self.half_width
        return np.where(np.abs(s) <= 1.0, P.polyval(s, coeffs), 0.0) / self.half_width**order


@dataclass(frozen=True, eq=False)
class PreparedSignals:
    """One recording made ready for the weak system (computed once, reused across the scan).

    Attributes
    ----------
    t, u, delta : ndarray
        The recorded samples.
    delta_smooth : ndarray
        Savitzky-Golay smoothed ``delta`` (for the play operator and the velocity sign).
    velocity_sign : ndarray
        ``sign(delta')`` from the smoothed derivative, zero where the speed is below the noise.
    speed : ndarray
        ``|delta'|`` from the smoothed derivative (0 where below the noise).
    jumps : ndarray of bool
        Command jumps per sample interval (:func:`tvcid.discovery.sindy.library.command_jumps`).
    starts : ndarray of int
        First sample of every test-function support.
    support : int
        Samples per support (odd).
    fine : int
        Fine-quadrature subdivisions per sample interval.
    """

    t: np.ndarray
    u: np.ndarray
    delta: np.ndarray
    delta_smooth: np.ndarray
    velocity_sign: np.ndarray
    speed: np.ndarray
    jumps: np.ndarray
    starts: np.ndarray
    support: int
    fine: int
    test_functions: BumpTestFunctions
    kind: str = "open"
    meta: dict = field(default_factory=dict)
    _memo: dict = field(default_factory=dict, repr=False)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])

    @property
    def n_rows(self) -> int:
        return int(self.starts.size)

    def fine_times(self):
        """Fine quadrature grid covering the whole record."""
        n = (self.t.size - 1) * self.fine + 1
        return self.t[0] + (self.dt / self.fine) * np.arange(n)

    def fine_delta(self):
        """Smoothed ``delta`` linearly interpolated on the fine grid."""
        return np.interp(self.fine_times(), self.t, self.delta_smooth)

    def fine_velocity_sign(self):
        """``sign(delta')`` held on the fine grid."""
        return np.repeat(self.velocity_sign, self.fine)[: (self.t.size - 1) * self.fine + 1]

    def fine_delayed_command(self, delay):
        """``u(t - Td)`` on the fine grid, edges of a square command kept sharp.

        The command is reconstructed once on the fine grid (:func:`delayed_command` with no
        delay); a delay shifts it by whole fine steps and interpolates the remaining fraction.
        """
        if "u_fine" not in self._memo:
            self._memo["u_fine"] = delayed_command(self.fine_times(), self.t, self.u, 0.0,
                                                   self.jumps)
        u_fine = self._memo["u_fine"]
        shift = delay / (self.dt / self.fine)
        whole = int(math.floor(shift + 1e-9))
        frac = max(shift - whole, 0.0)
        out = np.empty_like(u_fine)
        if whole >= u_fine.size:
            out[:] = u_fine[0]
            return out
        out[whole:] = u_fine[: u_fine.size - whole]
        out[:whole] = u_fine[0]
        if frac > 0:
            prev = np.empty_like(out)
            prev[1:] = out[:-1]
            prev[0] = out[0]
            out = (1.0 - frac) * out + frac * prev
        return out

    def phi(self, order, fine=False):
        """Samples of ``phi^(order)`` over one support (coarse or fine grid)."""
        key = ("phi", order, fine)
        if key not in self._memo:
            m = self.fine if fine else 1
            n = (self.support - 1) * m + 1
            half = (self.support - 1) // 2 * self.dt
            self._memo[key] = self.test_functions.derivative(order, np.linspace(-half, half, n))
        return self._memo[key]


def estimate_noise(delta):
    """Robust rms of white sensor noise on a smooth signal, from its third differences
    (:func:`tvcid.models.cycle_reading.white_noise_sd` of order 3: the smooth actuator output contributes
    little at 200 Hz-1 kHz; the median absolute deviation ignores steps)."""
    return white_noise_sd(delta, order=3)


def prepare_signals(t, u, delta, test_functions, delay_margin=0.0, smoothing=0.012,
                    fine_step=1e-4, kind="open", meta=None, noise=None):
    """Validate and prepare one recording's samples for :func:`weak_integrals`.

    Parameters
    ----------
    t, u, delta : array_like
        Uniform samples (s, rad, rad).
    test_functions : BumpTestFunctions
    delay_margin : float
        Supports start at least this long (s) after the first sample, so ``u(t - Td)`` is known.
    smoothing : float
        Savitzky-Golay window (s) for ``delta_smooth``.
    fine_step : float
        Target step (s) of the fine quadrature grid.
    noise : float or None
        Sensor noise rms (rad); sets the speed below which the velocity sign is taken as zero.

    Raises
    ------
    RecordingTooShortError
        When no support fits in the record.
    """
    t = np.asarray(t, dtype=float)
    u = np.asarray(u, dtype=float)
    delta = np.asarray(delta, dtype=float)
    dt = (t[-1] - t[0]) / (t.size - 1)
    if np.max(np.abs(np.diff(t) - dt)) > 1e-3 * dt:
        raise ValueError("the weak system needs uniformly sampled t")
    support = 2 * int(round(test_functions.half_width / dt)) + 1
    if support < 9:
        raise ValueError(
            f"test-function half width {test_functions.half_width} s spans fewer than 4 samples "
            f"at {1 / dt:g} Hz; use a wider test function"
        )
    stride = max(1, int(round((support - 1) * (1.0 - test_functions.overlap))))
    first = int(math.ceil((delay_margin + 2 * smoothing) / dt))
    starts = np.arange(first, t.size - support + 1, stride)
    if starts.size < 8:
        raise RecordingTooShortError(
            f"recording of {t[-1] - t[0]:.3g} s holds {starts.size} test-function supports of "
            f"{2 * test_functions.half_width:.3g} s after a {delay_margin:.3g} s delay margin; "
            "at least 8 are needed"
        )
    window = max(5, 2 * int(round(0.5 * smoothing / dt)) + 1)
    delta_smooth = savgol_filter(delta, window, 3, mode="interp")
    speed = savgol_filter(delta, window, 3, deriv=1, delta=dt, mode="interp")
    sigma = float(noise) if noise is not None else estimate_noise(delta)
    floor = 4.0 * sigma * float(np.linalg.norm(savgol_coeffs(window, 3, deriv=1, delta=dt)))
    velocity_sign = np.where(np.abs(speed) > floor, np.sign(speed), 0.0)
    jumps = command_jumps(u)
    if not jumps.any():
        # a continuous command (e.g. the controller output of a limit cycle): the fine grid only
        # has to resolve the dead zone's kinks and the delay, 1 ms is enough
        fine_step = max(fine_step, SMOOTH_COMMAND_STEP)
    fine = max(1, int(round(dt / fine_step)))
    return PreparedSignals(
        t=t, u=u, delta=delta, delta_smooth=delta_smooth, velocity_sign=velocity_sign,
        speed=np.where(velocity_sign != 0, np.abs(speed), 0.0),
        jumps=jumps, starts=starts, support=support, fine=fine,
        test_functions=test_functions, kind=kind, meta=dict(meta or {}),
    )


def weak_integrals(prepared, samples, order=0, fine=False, weights=None):
    """``int phi^(order)(t - c_i) f(t) dt`` for every test function ``i``.

    Parameters
    ----------
    prepared : PreparedSignals
    samples : ndarray
        ``f`` on the coarse grid (``fine=False``) or on the fine grid (``fine=True``).
    order : int
        Derivative order of ``phi``.
    weights : ndarray or None
        Quadrature weights over one support to use instead of ``phi^(order)`` (e.g. a combination
        ``phi'' - K2 phi' + K3 phi``).
    """
    m = prepared.fine if fine else 1
    length = (prepared.support - 1) * m + 1
    w = prepared.phi(order, fine) if weights is None else weights
    windows = sliding_window_view(np.asarray(samples, dtype=float), length)[prepared.starts * m]
    return (windows @ w) * (prepared.dt / m)
