"""Structure descriptions ("forms") of the actuator equation and their weak regression columns.

A form says where the nonlinear blocks sit, never what their values are.
Written in the measured output ``delta`` with ``L = d^2/dt^2 + K2 d/dt + K3``:

* dead zone on the error (paper 002, Fig. 1 and eq. 1; delay at the output)::

      delta''' + K2 delta'' + K3 delta' = K1 DZ_z(u(t-Td) - K play_r(delta)) [+ off L[sign delta']]

* dead zone and friction offset on the velocity signal (paper 001 section 4, paper 000): where the
  actuator moves, ``y(t - Td) = delta' - p + c sign(delta')`` with ``c = z - off`` inverts
  ``delta' = FRIC(DZ_z(y(t-Td) + p))``, so::

      delta''' + K2 delta'' + K3 delta' = K1 u(t-Td) - K1 K play_r(delta)(t - Td*)
                                          - c L[sign delta'] [+ s L[sat_1(G/s BP(delta'))]]

  with ``Td* = Td`` when the delay sits before the integrator (paper 001 final) and 0 when it sits
  at the output (paper 001 initial).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal as sps

from tvcid.models.linear import bandpass_transfer_function

from .library import play_along
from .weak import weak_integrals

__all__ = ["StructureForm", "FORMS", "UnknownFormError", "form_by_name", "TARGET"]

TARGET = "delta'''"

#: Velocity forms use the test functions over which the speed stays above this fraction of its
#: 99th percentile.
MOVING_FRACTION = 0.05


class UnknownFormError(ValueError):
    """Raised for a structure form name that :data:`FORMS` does not hold."""


@dataclass(frozen=True)
class StructureForm:
    """Where the dead zone, the friction offset, the band-pass loop and the delay sit.

    Parameters
    ----------
    name : str
    dead_zone_on : {"error", "velocity"}
        The signal the dead zone acts on (``DeadZonePosition``, ``docs/models.md#the-actuator``).
    friction : bool
        Offer the friction-offset term ``sign(delta')`` to the sparse regression.
    bandpass : bool
        Offer the positive band-pass loop term (paper 001 section 4).
    delay_inside_loop : bool
        Velocity forms: the delay sits before the integrator, inside the backlash loop (paper 001
        final) instead of at the output.
    """

    name: str
    dead_zone_on: str
    friction: bool = True
    bandpass: bool = False
    delay_inside_loop: bool = False

    # -- what the regression sees ------------------------------------------------------------
    def linear_terms(self):
        """Linear candidate terms; velocity forms omit ``delta`` (collinear with the play term)."""
        if self.dead_zone_on == "error":
            return ("delta''", "delta'", "delta")
        return ("delta''", "delta'")

    def term_names(self):
        """Library terms offered to the sparse regression, in column order."""
        names = list(self.linear_terms())
        if self.dead_zone_on == "error":
            names.append("DZ_z(u(t-Td)-K*play_r(delta))")
        else:
            names += ["u(t-Td)", "play_r(delta)(t-Td)" if self.delay_inside_loop else "play_r(delta)"]
        if self.friction:
            names.append("L[sign(delta')]")
        if self.bandpass:
            names.append("L[sat_1(G/s*BP(delta'))]")
        return tuple(names)

    def threshold_names(self):
        """Parameters entering nonlinearly that the weak residual scans.

        In the velocity forms the weak equation only holds while the actuator moves, where the
        backlash shifts the play output by ``r*sign(delta')`` and merges with the dead zone and the
        friction offset into one sign coefficient: ``z``, ``off`` and ``r`` are then found by
        simulation (:meth:`simulated_threshold_names`).
        """
        if self.dead_zone_on == "error":
            return ("dead_zone", "backlash", "delay")
        return ("delay", "bandpass_ratio") if self.bandpass else ("delay",)

    def simulated_threshold_names(self):
        """Parameters the estimator scans on simulations of the recordings instead."""
        return () if self.dead_zone_on == "error" else ("dead_zone", "backlash", "delay")

    def admissible(self, coefficients):
        """Whether lifted least-squares coefficients describe a physical actuator.

        ``K1, K2, K3 > 0`` (a stable, positive-gain second-order block) and, in velocity forms, a
        backlash feedback of the same sign as the command's gain (``K > 0``).
        """
        c = coefficients
        if c["delta''"] >= 0 or c["delta'"] >= 0:
            return False
        if self.dead_zone_on == "error":
            return c[self.term_names()[3]] > 0
        play = c.get("play_r(delta)(t-Td)", c.get("play_r(delta)", 0.0))
        return c["u(t-Td)"] > 0 and play < 0

    def row_mask(self, prepared, speed_floor=None):
        """Test functions the form's equation holds on.

        The velocity forms invert the dead zone and the friction offset, which is only possible
        while the actuator moves clearly: supports where the speed falls below
        :data:`MOVING_FRACTION` of its 99th percentile (a standstill, a reversal, the small
        dither of the band-pass loop) are dropped; ``speed_floor`` (rad/s) overrides that floor,
        so that one floor serves several recordings.
        """
        if self.dead_zone_on == "error":
            return np.ones(prepared.n_rows, dtype=bool)
        floor = speed_floor
        if floor is None:
            floor = MOVING_FRACTION * float(np.percentile(prepared.speed, 99))
        moving = prepared.speed > floor
        stopped = np.concatenate([[0], np.cumsum(~moving)])
        n = prepared.support
        return (stopped[prepared.starts + n] - stopped[prepared.starts]) == 0

    def columns(self, prepared, thresholds, lifted=True, linear=None, cache=None):
        """Weak target and columns on one recording.

        Parameters
        ----------
        prepared : tvcid.discovery.sindy.weak.PreparedSignals
        thresholds : dict
            Values of :meth:`threshold_names` (``feedback_gain`` optional, default 1).
        lifted : bool
            Give ``L[q]`` terms as three free columns ``q, q', q''`` (linear in the unknowns;
            used while scanning) instead of one column weighted by ``linear = (K2, K3)``.
        cache : dict or None
            Reused between calls on the same recording (play operator, band-pass output).

        Returns
        -------
        target : ndarray
        columns : dict of str -> ndarray
        noise_weights : dict of str -> ndarray
            Coarse quadrature weights of the columns (and ``TARGET``) linear in ``delta``, for the
            bias compensation of :mod:`tvcid.discovery.sindy.estimator`.
        """
        cache = {} if cache is None else cache
        p = prepared
        r = float(thresholds.get("backlash", 0.0))
        td = float(thresholds.get("delay", 0.0))
        gain_k = float(thresholds.get("feedback_gain", 1.0))
        if ("linear",) not in cache:
            cache[("linear",)] = (
                -weak_integrals(p, p.delta, 3),
                {
                    "delta''": weak_integrals(p, p.delta, 2),
                    "delta'": -weak_integrals(p, p.delta, 1),
                    "delta": weak_integrals(p, p.delta, 0),
                },
            )
        target, linear_cols = cache[("linear",)]
        cols = {name: linear_cols[name] for name in self.linear_terms()}
        noise = {
            TARGET: -p.phi(3), "delta''": p.phi(2), "delta'": -p.phi(1), "delta": p.phi(0),
        }
        key = ("fine_delta",)
        if key not in cache:
            cache[key] = p.fine_delta()
        d_fine = cache[key]
        key = ("play", r)
        if key not in cache:
            cache[key] = play_along(d_fine, r) if r > 0 else d_fine
        b = cache[key]
        key = ("u", td)
        if key not in cache:
            cache[key] = p.fine_delayed_command(td)
        u_td = cache[key]
        if self.dead_zone_on == "error":
            z = float(thresholds.get("dead_zone", 0.0))
            e = u_td - gain_k * b
            dz = np.maximum(e - z, 0.0) + np.minimum(e + z, 0.0)  # DZ_z, paper 002 eq. 3
            cols[self.term_names()[3]] = weak_integrals(p, dz, 0, True)
        else:
            cols["u(t-Td)"] = weak_integrals(p, u_td, 0, True)
            if self.delay_inside_loop:
                shift = td / (p.dt / p.fine)
                b_td = np.interp(np.arange(b.size) - shift, np.arange(b.size), b, left=b[0])
                cols["play_r(delta)(t-Td)"] = weak_integrals(p, b_td, 0, True)
            else:
                cols["play_r(delta)"] = weak_integrals(p, b, 0, True)
        extra = []
        if self.friction:
            if ("sign",) not in cache:
                cache[("sign",)] = p.fine_velocity_sign()
            extra.append(("L[sign(delta')]", cache[("sign",)]))
        if self.bandpass:
            ratio = float(thresholds["bandpass_ratio"])
            key = ("bp",)
            if key not in cache:
                cache[key] = _bandpass_of_velocity(p)
            extra.append(("L[sat_1(G/s*BP(delta'))]", np.clip(ratio * cache[key], -1.0, 1.0)))
        for name, q in extra:
            if lifted:
                key = ("lifted", name, float(thresholds.get("bandpass_ratio", 0.0)))
                if key not in cache:
                    cache[key] = (
                        weak_integrals(p, q, 0, True),
                        -weak_integrals(p, q, 1, True),
                        weak_integrals(p, q, 2, True),
                    )
                cols[name], cols[name + "'"], cols[name + "''"] = cache[key]
            else:
                k2, k3 = linear
                w = p.phi(2, True) - k2 * p.phi(1, True) + k3 * p.phi(0, True)
                cols[name] = weak_integrals(p, q, weights=w, fine=True)
        return target, cols, noise


def _bandpass_of_velocity(prepared):
    """``BP(delta')`` on the fine grid as the strictly proper filter ``s*BP(s)`` of ``delta``.

    The 9-10 Hz, 4th-order Butterworth band-pass of ``docs/models.md#conventions``, applied to the
    smoothed ``delta`` so that the velocity is never differentiated numerically.
    """
    num, den = bandpass_transfer_function(9.0, 10.0, 2)
    num = np.trim_zeros(np.polymul(np.ravel(num), [1.0, 0.0]), "f")
    t = prepared.fine_times()
    system = sps.lti(num, den)
    _, y, _ = sps.lsim(system, prepared.fine_delta() - prepared.delta_smooth[0], t - t[0])
    return y


FORMS = {
    form.name: form
    for form in (
        StructureForm("dead_zone_on_error", "error", friction=True),
        StructureForm("dead_zone_on_velocity", "velocity", friction=True),
        StructureForm("dead_zone_on_velocity_delay_in_loop", "velocity", friction=True,
                      delay_inside_loop=True),
        StructureForm("dead_zone_on_velocity_bandpass", "velocity", friction=True, bandpass=True,
                      delay_inside_loop=True),
    )
}


def form_by_name(name):
    """The :class:`StructureForm` called ``name``; :class:`UnknownFormError` names the choices."""
    if isinstance(name, StructureForm):
        return name
    try:
        return FORMS[name]
    except KeyError:
        raise UnknownFormError(
            f"unknown structure form {name!r}; choose one of {', '.join(FORMS)}"
        ) from None
