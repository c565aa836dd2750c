"""Paper 002's inverse method: backlash and dead zone from a measured limit cycle.

From the HWIL cycle's amplitude ``K1`` (rad, at the actuator output) and frequency ``w`` and the
controller, paper 002 section 5 derives the nonlinear parameters from the harmonic-balance
condition ``Gm(jw) Gp(jw) = -1`` (eqs. 6-18):

* :func:`paper002_family`: the one-parameter family of (backlash, dead zone) pairs of eqs. 13-18,
  either ``variant="printed"`` (the equations as printed) or ``variant="corrected"`` with the three
  slips ``docs/models.md#errata`` lists: eq. 15 is ``KK = (1 + cot^2 theta)/|Gp|^2``, eq. 16's last
  term is ``c^2 KK`` with ``c = K3 w - w^3``, eq. 18 is ``X_z = K1 w/(37 Z)`` (``Z`` the dead-zone
  DF, not ``Zx = 37*34100 Z``). These equations keep the modulus and ``tan`` of the phase condition
  only, so the family satisfies eq. 13 and eq. 14 up to a half-turn of phase; the paper says the
  real solution "must satisfy Eq. (12)".
* :func:`solve_backlash_and_dead_zone`: the exact harmonic balance (eq. 12, phase and modulus),
  for any hypothesis :class:`~tvcid.discovery.describing.actuator_loop.ActuatorDescribingLoop` treats.
  At controller A (4.89e-3 rad at 8.57 rad/s) with paper 002's 7 ms output delay it has *no*
  solution: the phase condition would need a backlash describing function whose real part exceeds
  1, which no play operator has. It raises :class:`NoHarmonicBalanceSolution` saying so instead of
  returning a wrong pair. With paper 001's model (dead zone on the velocity signal, ``K`` in the
  feedback, 5.6 ms) it gives ``f = 1.237e-4`` (the paper printed 1.1625e-4).

Widths are half widths; paper 002's ``f`` in eq. 5 is the half width (its section-6 value is a
full width, see :func:`tvcid.models.nonlinearities.backlash_half_width_from_full`).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import brentq

from tvcid.models.experiments import ClosedLoop
from tvcid.models.hypotheses import ActuatorParams, DeadZonePosition, DelayPosition

from . import analytic
from .actuator_loop import ActuatorDescribingLoop, describe_controller, vehicle_controller_response
from .errors import NoHarmonicBalanceSolution, UnsupportedStructureError

__all__ = [
    "FAMILY_BACKLASH_HALF_WIDTHS",
    "BacklashDeadZoneFamily",
    "BacklashDeadZonePair",
    "paper002_family",
    "solve_backlash_and_dead_zone",
]

#: Backlash half widths (rad) at which ``docs/models.md#errata`` tabulates the corrected family.
FAMILY_BACKLASH_HALF_WIDTHS = (1e-4, 2e-4, 3e-4, 4e-4, 4.364e-4, 5e-4, 7e-4, 1e-3)
VARIANTS = ("corrected", "printed")


def _check_cycle(amplitude, frequency):
    for name, value in (("amplitude", amplitude), ("frequency", frequency)):
        if not (np.isfinite(value) and value > 0):
            raise ValueError(f"the measured {name} must be a finite number > 0 (got {value!r})")
    return float(amplitude), float(frequency)


@dataclass(frozen=True, eq=False)
class BacklashDeadZoneFamily:
    """Pairs (backlash half width, dead zone) that paper 002's equations accept for one cycle.

    Attributes
    ----------
    backlash_half_width, dead_zone : ndarray
        The family (rad); ``dead_zone`` is NaN where the variant's equations have no root.
    variant : str
        ``"corrected"`` or ``"printed"``.
    amplitude, frequency, delay : float
        The measured cycle (rad, rad/s) and the output delay used (s).
    note : str
    """

    backlash_half_width: np.ndarray
    dead_zone: np.ndarray
    variant: str
    amplitude: float
    frequency: float
    delay: float
    note: str = field(default="", repr=False)

    def to_dict(self) -> dict:
        return {
            "variant": self.variant,
            "amplitude": self.amplitude,
            "frequency": self.frequency,
            "delay": self.delay,
            "note": self.note,
            "family": [
                {"backlash_half_width": float(f), "dead_zone": (None if np.isnan(z) else float(z))}
                for f, z in zip(self.backlash_half_width, self.dead_zone)
            ],
        }

    def plot(self, ax=None, **kwargs):
        """Dead zone against backlash half width. Creates a figure only when ``ax`` is None."""
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        ax.plot(self.backlash_half_width, self.dead_zone, "o-", label=kwargs.pop("label", self.variant), **kwargs)
        ax.set_xlabel("backlash half width r (rad)")
        ax.set_ylabel("dead zone zm (rad)")
        ax.set_title(f"paper 002 family: {self.amplitude:.3g} rad at {self.frequency:.3g} rad/s, Td {self.delay:g} s")
        ax.legend()
        return ax


def _check_params(params):
    if not isinstance(params, ActuatorParams):
        raise TypeError(f"params must be an ActuatorParams (e.g. tvcid.models.M002()), got {type(params).__name__}")


def _paper002_structure(params: ActuatorParams, delay):
    if params.dead_zone_position is not DeadZonePosition.ERROR:
        raise UnsupportedStructureError(
            f"paper 002's eqs. 13-18 assume the dead zone on the actuator error; {params.name} has it "
            f"on the {params.dead_zone_position.value} signal (use solve_backlash_and_dead_zone)"
        )
    if params.has_bandpass_loop or params.friction_offset != 0:
        raise UnsupportedStructureError(
            f"paper 002's eqs. 13-18 have no friction offset or band-pass loop; {params.name} has them"
        )
    if delay is None:
        delay = params.delay
        if delay > 0 and params.delay_position is not DelayPosition.OUTPUT:
            raise UnsupportedStructureError(
                f"paper 002's eq. 11 puts the delay at the output; {params.name} has it "
                f"{params.delay_position.value}"
            )
    delay = float(delay)
    if not (np.isfinite(delay) and delay >= 0):
        raise ValueError(f"delay must be a finite number >= 0 (got {delay!r})")
    return delay


def paper002_family(
    amplitude,
    frequency,
    controller: ClosedLoop,
    params: ActuatorParams,
    delay=None,
    backlash_half_widths=FAMILY_BACKLASH_HALF_WIDTHS,
    variant="corrected",
) -> BacklashDeadZoneFamily:
    """Paper 002 eqs. 13-18: the dead zone ``zm`` that goes with each backlash half width.

    Parameters
    ----------
    amplitude : float
        ``K1``: measured cycle amplitude at the actuator output (rad).
    frequency : float
        ``w``: measured cycle frequency (rad/s).
    controller : tvcid.models.ClosedLoop
        ``Kp, Kd, mu`` of ``Gp`` (eq. 7): a continuous PD without compensator or bending mode.
    params : tvcid.models.ActuatorParams
        Structure (dead zone on the error, delay at the output), linear part
        ``gain/(s^2 + damping s + stiffness)`` and ``feedback_gain``; :class:`tvcid.models.M002` is
        paper 002's eq. 1. Its widths are ignored.
    delay : float, optional
        Output delay ``Td`` (s); default ``params.delay``.
    backlash_half_widths : array_like
        Backlash half widths ``f`` (rad) of eq. 5.
    variant : {"corrected", "printed"}

    Returns
    -------
    BacklashDeadZoneFamily

    Raises
    ------
    UnsupportedStructureError
        For a structure or delay position eqs. 13-18 do not model, or a controller other than
        the continuous PD (a compensator, bending mode or hold).

    Notes
    -----
    With ``K1g = gain``, ``K2 = damping``, ``K3 = stiffness``, ``F = Rf + j If`` the backlash DF
    (times ``feedback_gain``), ``theta = pi + atan(Kd w) - Td w`` and ``c = K3 w - w^3``:

    * corrected: ``KK = (1 + cot^2 theta)/|Gp|^2``;
      ``Zx = c (If KK + sqrt(KK))/(1 - If^2 KK)`` (eq. 17, the root of the corrected eq. 16);
      ``X_z = K1 w/(dc Z)`` with ``Z = Zx/K1g`` and ``dc = K1g/K3`` (37 in paper 002);
      ``zm = X_z rho`` where the dead-zone DF at ``zm/X_z = rho`` equals ``Z`` (eq. 3).
    * printed: ``KK = ((1 + 1/tan theta)/|Gp|)^2`` (eq. 15); ``Zx`` the positive root of eq. 16
      as printed (last term ``c KK``; eq. 17 as printed is the root of the *corrected* eq. 16);
      ``X_z = K1 w/(37 Zx)`` (eq. 18 as printed).
    """
    amplitude, frequency = _check_cycle(amplitude, frequency)
    if not controller.is_plain_pd or controller.sample_rate is not None:
        # eqs. 13-18 carry the PD's phase atan(Kd w) in closed form: any other controller would
        # enter through |Gp| but not through theta
        raise UnsupportedStructureError(
            f"paper 002's eqs. 13-18 assume the continuous PD of eq. 7; this controller "
            f"({describe_controller(controller)}) is not one: use solve_backlash_and_dead_zone"
        )
    if variant not in VARIANTS:
        raise ValueError(f"variant must be one of {', '.join(VARIANTS)} (got {variant!r})")
    _check_params(params)
    delay = _paper002_structure(params, delay)
    widths = np.atleast_1d(np.asarray(backlash_half_widths, dtype=float))
    if np.any(~np.isfinite(widths)) or np.any(widths < 0):
        raise ValueError(f"backlash half widths must be finite and >= 0 (got {backlash_half_widths!r})")
    w, k1 = frequency, amplitude
    k1g, k3 = params.gain, params.stiffness
    dc_gain = k1g / k3
    gp = abs(complex(vehicle_controller_response(controller, w)))
    theta = np.pi + np.arctan(controller.kd * w) - delay * w
    c = k3 * w - w ** 3
    dead_zone = np.full(widths.shape, np.nan)
    for i, f in enumerate(widths):
        imag = params.feedback_gain * complex(analytic.backlash_df(k1, f)).imag
        if variant == "corrected":
            kk = (1.0 + 1.0 / np.tan(theta) ** 2) / gp ** 2
            zx = c * (imag * kk + np.sqrt(kk)) / (1.0 - imag ** 2 * kk)
            z_gain = zx / k1g
            x_z = k1 * w / (dc_gain * z_gain)
        else:
            kk = ((1.0 + 1.0 / np.tan(theta)) / gp) ** 2
            qa, qb, qc = 1.0 - imag ** 2 * kk, -2.0 * c * imag * kk, -c * kk
            disc = qb * qb - 4 * qa * qc
            if disc < 0 or qa == 0:
                continue
            zx = (-qb + np.sqrt(disc)) / (2 * qa)
            z_gain = zx / k1g
            x_z = k1 * w / (dc_gain * zx)
        if 0.0 < z_gain < 1.0:
            dead_zone[i] = x_z * analytic.inverse_dead_zone_df(z_gain)
    note = (
        "eqs. 13-18 with the three corrections of docs/models.md#errata; the family satisfies the "
        "modulus and the tangent of the phase condition, not necessarily the phase itself (see solve_backlash_and_dead_zone)"
        if variant == "corrected"
        else "eqs. 15, 16 and 18 as printed (three slips); not dimensionally consistent, shown for the record"
    )
    return BacklashDeadZoneFamily(widths, dead_zone, variant, amplitude, frequency, delay, note)


@dataclass(frozen=True)
class BacklashDeadZonePair:
    """One exact harmonic-balance solution of the inverse problem.

    Attributes
    ----------
    backlash_half_width, dead_zone : float
        Half widths (rad; the dead zone in the unit of the signal it acts on).
    backlash_df, dead_zone_df : complex, float
        The describing functions at the cycle.
    dead_zone_input_amplitude : float
    """

    backlash_half_width: float
    dead_zone: float
    backlash_df: complex
    dead_zone_df: float
    dead_zone_input_amplitude: float

    def to_dict(self) -> dict:
        return {
            "backlash_half_width": self.backlash_half_width,
            "dead_zone": self.dead_zone,
            "backlash_df": [self.backlash_df.real, self.backlash_df.imag],
            "dead_zone_df": self.dead_zone_df,
            "dead_zone_input_amplitude": self.dead_zone_input_amplitude,
        }


def solve_backlash_and_dead_zone(
    amplitude, frequency, controller: ClosedLoop, params: ActuatorParams, n_grid=4000
):
    """Exact harmonic balance ``1 + H P N/(jw) = 0`` for the backlash and the dead zone.

    With the cycle ``(a, w)`` given, the phase condition involves the backlash only (the dead
    zone's DF is real): it is solved for the half width ``r`` in ``[0, a)``; the modulus then fixes
    the dead-zone gain ``N`` and eq. 3 the width ``z``.

    Parameters
    ----------
    amplitude, frequency : float
        Measured cycle at the actuator output (rad, rad/s).
    controller : tvcid.models.ClosedLoop
        Any controller: ``Gp`` is :func:`~.actuator_loop.vehicle_controller_response`
        (compensator, bending mode, a hold as its first harmonic).
    params : tvcid.models.ActuatorParams
        Structure, linear part, delay and its position (e.g. :class:`tvcid.models.M002` for paper 002,
        :class:`tvcid.models.M001i` for paper 001 section 2); its backlash and dead-zone values are
        ignored.

    Returns
    -------
    tuple of BacklashDeadZonePair
        Every solution, by increasing backlash.

    Raises
    ------
    NoHarmonicBalanceSolution
        When no backlash meets the phase condition, or the modulus needs a dead-zone gain outside
        (0, 1); the message gives the describing function the phase would need.
    """
    amplitude, frequency = _check_cycle(amplitude, frequency)
    _check_params(params)
    if params.friction_offset != 0 or params.has_bandpass_loop:
        raise UnsupportedStructureError(
            f"{params.name}: the inverse solve treats a dead zone and a backlash only "
            f"(friction_offset={params.friction_offset:g}, bandpass_gain={params.bandpass_gain:g}); "
            "set both to 0"
        )
    loop = ActuatorDescribingLoop(params.replace(backlash=0.0), controller)
    a, w = amplitude, frequency
    h = complex(loop.forward_response(w))
    gp_out = complex(vehicle_controller_response(controller, w) * loop.delay_factor(w, DelayPosition.OUTPUT))
    k = params.feedback_gain
    ratios = np.linspace(0.0, 1.0, int(n_grid) + 1)[:-1]

    def open_loop(ratio):
        return h * (gp_out + k * complex(analytic.backlash_df(a, ratio * a))) / (1j * w)

    f_curve = np.array([complex(analytic.backlash_df(a, r * a)) for r in ratios])
    l_curve = h * (gp_out + k * f_curve) / (1j * w)
    sign = np.sign(l_curve.imag)
    pairs = []
    for i in np.flatnonzero(sign[:-1] * sign[1:] < 0):
        ratio = brentq(lambda r: open_loop(r).imag, ratios[i], ratios[i + 1], xtol=1e-15)
        l_value = open_loop(ratio)
        if l_value.real >= 0:
            continue
        gain = -1.0 / l_value.real
        if not 0.0 < gain < 1.0:
            continue
        r = ratio * a
        f_value = complex(analytic.backlash_df(a, r))
        p_ret = gp_out + k * f_value
        q = a * abs(p_ret) if params.dead_zone_position is DeadZonePosition.ERROR else a * abs(h * p_ret)
        z = q * analytic.inverse_dead_zone_df(gain)
        pairs.append(BacklashDeadZonePair(float(r), float(z), f_value, float(gain), float(q)))
    if pairs:
        return tuple(pairs)
    # Explain: the F the phase condition needs lies on the ray P = t exp(j phi), t > 0.
    phi = np.pi - np.angle(h / (1j * w))
    direction = np.exp(1j * phi)
    imag_targets = f_curve.imag
    # on the ray, F = (t direction - gp_out)/k; where its imaginary part equals the curve's:
    t = (k * imag_targets + gp_out.imag) / direction.imag if abs(direction.imag) > 1e-15 else np.full_like(imag_targets, np.nan)
    needed_real = ((t * direction - gp_out) / k).real
    valid = t > 0
    detail = ""
    if np.any(valid):
        j = int(np.argmin(np.where(valid, needed_real - f_curve.real, np.inf)))
        detail = (
            f"; the phase condition would need the backlash describing function to have real part "
            f"{needed_real[j]:.4g} where a play operator of half width {ratios[j] * a:.3g} rad gives "
            f"{f_curve.real[j]:.4g} (a play operator's real part never exceeds 1)"
        )
    raise NoHarmonicBalanceSolution(
        f"no exact harmonic-balance solution for {params.name} at {a:.4g} rad, {w:.4g} rad/s with "
        f"a {params.delay * 1e3:.4g} ms {params.delay_position.value} delay (Kp {controller.kp:g}, "
        f"Kd {controller.kd:g}, mu {controller.mu:g}): no backlash with a dead-zone gain in (0, 1) "
        f"balances the loop{detail}. The describing-function approximation is off here; paper 002's "
        "family (paper002_family) keeps only the tangent of the phase"
    )
