"""The first-harmonic model of an actuator hypothesis in the HWIL closed loop.

Every transfer function comes from the :class:`tvcid.models.ActuatorParams` object (``linear_block()``,
``feedback_gain``, ``delay``, ``delay_position``) and the :class:`tvcid.models.ClosedLoop` controller;
nothing here is specific to one hypothesis. With ``x = a sin(wt)`` the integrator output and
``s = jw`` (paper 002 Figs. 5 and 7, eqs. 7-12; paper 001 section 2)::

    controller and vehicle    Gp(s) = C(s) V(s)                     (paper 002 eq. 7 generalised)
                              C = Kp (1 + Kd s) F(s) [x ZOH factor], V = mu/s^2 [+ bending]
                              plain PD: Gp = Kp mu (1 + Kd s)/s^2   (paper 002 eq. 7)
    delays                    D(s) = exp(-s Td) at the chosen position, 1 elsewhere
    second-order block        G2(s) = K1/(s^2 + K2 s + K3), or K1 D/(s^2 + D (K2 s + K3)) with
                              the delay before the first integrator (paper 000 Fig. 8)
    backlash feedback         F(a) = play-operator DF, half width r (paper 002 eqs. 4-5; not
                              the compensator F(s))
    return path               P = Gp D_out + K F(a),  so  e = -P x
    forward path              H = D_bi G2
    loop equation             1 + H(jw) P(jw, a) N(q) / (jw) = 0

``Gp`` is :meth:`tvcid.models.ClosedLoop.controller_response` times
:meth:`tvcid.models.ClosedLoop.vehicle_response`: the controller is ``u = -C theta_m`` and the sensed
attitude ``theta_m = V delta``, so ``u = -Gp delta`` and the sign of eq. 7 carries over to any
compensator ``F`` (lead/lag, notch, any proper controller) and bending mode
(:mod:`tvcid.models.controllers`). A controller held at ``sample_rate`` (zero-order hold, as the HWIL's
200 Hz computer) enters through its first harmonic only: ``C`` is multiplied by the hold's
``(1 - exp(-sT))/(sT) = exp(-jwT/2) sin(wT/2)/(wT/2)`` with ``F`` as its Tustin realisation. That
is an approximation on top of the describing function's: it keeps the half-sample delay and the
hold's attenuation and drops the aliased images at ``2 pi k/T +- w`` (far above the cycle, and
filtered by ``mu/s^2`` before the sampler sees them). At 200 Hz and the cycle's 8.9 rad/s the
sinc is 1 - 9e-5, so the hold is in effect 2.5 ms more delay, which the simulator confirms (held
vs continuous with that delay added: within 3.2e-4). For M002 at controller A the hold raises
the DF's first harmonic by 13.0 % and its frequency by 0.28 %, against 13.8 % and 0.81 %
simulated: the DF's frequency responds to delay a third as strongly as the simulator's
(``tests/test_describing_controllers.py``).

A compensator moves the DF's cycle the way the simulator moves it (lead: up in frequency, down in
amplitude; lag or a notch at the cycle: down and up, or no cycle where the simulated loop
diverges), but the first-harmonic error grows with the lead: for M002 at controller A, leads
centred on 8.6 rad/s with pole/zero ratios 1.2, 2 and 4 give DF errors of +6 %, +16 % and +10 % in
frequency and +12 %, +25 % and +12 % in amplitude; a lag (ratio 1.2) +1 % and +3 %, a shallow
notch at 8.6 rad/s +3 % and +1 % (:data:`COMPENSATOR_CAVEAT`; :func:`tvcid.models.simulate` and a
stand-alone RK4, 4e-5 apart).

``N`` is the dead zone's describing function (paper 002 eq. 3), or that of ``FRIC(DZ(.))`` when a
friction offset acts (paper 001 section 3). Its input amplitude is ``q = a |P|`` with the dead
zone on the error (paper 002) and ``q = a |H P|`` with it on the velocity-level signal (papers
001 and 000).

The band-pass feedback loop of papers 001 (final) and 000, ``w = FRIC(DZ(v + p))``,
``p = sat_s(G BP(w))``, is balanced at the fundamental too. With ``q = v + p`` of amplitude ``Q``
as the search variable, ``w = N(Q) q``, the saturation's input has amplitude
``S = G |BP(jw)| N Q`` and ``p = N_sat(S) G BP(jw) w``, so ``v = q (1 - N_sat G BP N)``, the
integrator output has amplitude ``a = N Q/w`` and the loop equation becomes

    1 - N_sat(S) G BP(jw) N(Q) + H(jw) P(jw, a) N(Q)/(jw) = 0.

This is a first-harmonic balance only: the 7th harmonic that the loop raises in simulation (and that
saturates it there) is beyond it, so at the cycle near 8.6 rad/s the loop hardly changes the
prediction (M001f at controller A: 5.698e-3 rad at 8.514 rad/s against a simulated first harmonic of
5.697e-3 at 8.589). It also finds a small cycle of the loop in its pass band (59.6 rad/s, 4.5e-5
rad, "stable" by Loeb) for M001f and for M000 with G 48 and saturation 0.015. That one is *not*
confirmed by the simulator: the small cycle M000 does reach from x(0) = 0, y(0) = 0.1
(``docs/models.md#m000``) is at 13.8 rad/s with 2.4e-4 rad, which this balance does not find. A
band-pass loop with the dead zone on the error raises :class:`UnsupportedStructureError`.

Known limit of the approximation (``docs/models.md#errata``): for M002 at controller A it predicts
8.88 rad/s where the simulator gives 8.60, and 8.80 even with no backlash: the cycle is far from a
sinusoid at the dead zone's output, so expect a few per cent in frequency and about 7 % in
amplitude.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tvcid.models.experiments import ClosedLoop
from tvcid.models.hypotheses import ActuatorParams, DeadZonePosition, DelayPosition
from tvcid.models.linear import bandpass_transfer_function

from . import analytic
from .errors import AmplitudeBelowDeadZoneError, UnsupportedStructureError
from .harmonic_balance import HarmonicBalanceResult, solve_harmonic_balance

__all__ = [
    "ActuatorDescribingLoop",
    "predict_limit_cycles",
    "vehicle_controller_response",
    "describe_controller",
    "DF_CAVEAT",
    "BANDPASS_CAVEAT",
    "COMPENSATOR_CAVEAT",
]

#: What a user should know before trusting a first-harmonic prediction of these loops.
DF_CAVEAT = (
    "first-harmonic approximation: for M002 at controller A it predicts 8.88 rad/s and a "
    "first harmonic of 5.90e-3 rad against 8.60 rad/s and 5.52e-3 simulated "
    "(docs/models.md#errata); use it to draw families and as a starting guess, not as a likelihood"
)

#: What a compensator does to the approximation (measured, see the module docstring).
COMPENSATOR_CAVEAT = (
    "with a compensator the DF gets the direction of the shift right but its error grows: for "
    "M002 at controller A with leads centred on 8.6 rad/s it is up to +16 % in frequency and "
    "+25 % in amplitude against a simulation"
)

#: The band-pass loop is balanced at the fundamental only.
BANDPASS_CAVEAT = (
    "the band-pass loop is balanced at the fundamental only: the 7th harmonic it raises and that "
    "saturates it in simulation is beyond a first-harmonic balance; a small cycle it finds in the "
    "loop's pass band (near 60 rad/s) is not confirmed by simulation"
)


def vehicle_controller_response(controller: ClosedLoop, frequency):
    """``Gp(jw) = C(jw) V(jw)``: controller times vehicle, so that ``u = -Gp delta``.

    For the papers' continuous PD and rigid vehicle this is ``Kp mu (1 + Kd jw)/(jw)^2`` (paper
    002 eq. 7; equal to that formula to rounding, 6e-16 relative, as the factors are multiplied
    in another order; predicted cycles move by 2e-15 at most). With a
    compensator, a bending mode or a zero-order hold it is
    :meth:`tvcid.models.ClosedLoop.controller_response` times :meth:`tvcid.models.ClosedLoop.vehicle_response`
    (see the module docstring for the hold's first-harmonic approximation).

    Parameters
    ----------
    controller : tvcid.models.ClosedLoop
    frequency : array_like
        rad/s.

    Returns
    -------
    complex ndarray
    """
    w = np.asarray(frequency, dtype=float)
    return controller.controller_response(w) * controller.vehicle_response(w)


def describe_controller(controller: ClosedLoop) -> str:
    """One line naming the controller's gains and its optional parts, for labels and reports.

    Parameters
    ----------
    controller : tvcid.models.ClosedLoop

    Returns
    -------
    str
        E.g. ``"Kp 5.84, Kd 0.062, mu 12.3, F lead, held at 200 Hz (first harmonic)"``.
    """
    text = f"Kp {controller.kp:g}, Kd {controller.kd:g}, mu {controller.mu:g}"
    if controller.compensator is not None:
        text += f", F {controller.compensator.name}"
    if controller.bending is not None:
        text += f", bending {controller.bending.frequency:g} rad/s"
    if controller.sample_rate is not None:
        text += f", held at {controller.sample_rate:g} Hz (first harmonic)"
    return text


@dataclass(frozen=True)
class ActuatorDescribingLoop:
    """A hypothesis and a controller as a first-harmonic loop (see the module docstring).

    Parameters
    ----------
    params : tvcid.models.ActuatorParams
    controller : tvcid.models.ClosedLoop

    Any :class:`tvcid.models.ClosedLoop`: PD, compensator, bending mode, continuous or held (the hold
    as its first harmonic, see the module docstring).

    Raises
    ------
    UnsupportedStructureError
        For a band-pass feedback loop or a friction offset with the dead zone on the error.
    """

    params: ActuatorParams
    controller: ClosedLoop

    def __post_init__(self):
        p = self.params
        if not isinstance(p, ActuatorParams):
            raise TypeError(f"params must be an ActuatorParams, got {type(p).__name__}")
        if not isinstance(self.controller, ClosedLoop):
            raise TypeError(f"controller must be a ClosedLoop, got {type(self.controller).__name__}")
        if p.has_bandpass_loop and p.dead_zone_position is DeadZonePosition.ERROR:
            raise UnsupportedStructureError(
                f"{p.name} has a band-pass feedback loop (bandpass_gain={p.bandpass_gain:g}) with the "
                "dead zone on the error: the loop's input is then not the dead zone's, a structure the "
                "describing-function loop does not treat; set bandpass_gain=0 or put the dead zone on "
                "the velocity signal"
            )
        if p.friction_offset != 0 and p.dead_zone_position is DeadZonePosition.ERROR:
            raise UnsupportedStructureError(
                f"{p.name}: a friction offset ({p.friction_offset:g}) with the dead zone on the "
                "error puts two static nonlinearities at different points of the loop; the "
                "describing-function loop treats FRIC(DZ(.)) only with the dead zone on the "
                "velocity signal"
            )

    # -- linear parts ---------------------------------------------------------------------------
    def delay_factor(self, frequency, position: DelayPosition):
        """``exp(-jw Td)`` when the hypothesis's delay sits at ``position``, else 1."""
        p = self.params
        w = np.asarray(frequency, dtype=float)
        if p.delay > 0 and p.delay_position is DelayPosition(position):
            return np.exp(-1j * w * p.delay)
        return np.ones_like(w, dtype=complex)

    def second_order_response(self, frequency):
        """``G2(jw)`` from :meth:`ActuatorParams.linear_block`, the delay folded in when it acts
        before the first integrator (``y'' = [K1 g - K3 y - K2 y'](t - Td)``)."""
        num, den = self.params.linear_block()
        s = 1j * np.asarray(frequency, dtype=float)
        den = np.asarray(den, dtype=float)
        leading = den[0] * s ** (den.size - 1)
        rest = np.polyval(den, s) - leading
        d = self.delay_factor(frequency, DelayPosition.BEFORE_FIRST_INTEGRATOR)
        return d * np.polyval(num, s) / (leading + d * rest)

    def forward_response(self, frequency):
        """``H = D_bi G2``: from the actuator error to the integrator's input (before the dead
        zone when it acts on the velocity signal)."""
        return self.delay_factor(frequency, DelayPosition.BEFORE_INTEGRATOR) * self.second_order_response(frequency)

    def bandpass_response(self, frequency):
        """``G BP(jw)``: the band-pass loop's gain and Butterworth filter (paper 001 section 4,
        :func:`tvcid.models.linear.bandpass_transfer_function`); 0 without the loop."""
        p = self.params
        w = np.asarray(frequency, dtype=float)
        if not p.has_bandpass_loop:
            return np.zeros_like(w, dtype=complex)
        num, den = bandpass_transfer_function(p.bandpass_low_hz, p.bandpass_high_hz, p.bandpass_order)
        s = 1j * w
        return p.bandpass_gain * np.polyval(num, s) / np.polyval(den, s)

    def velocity_nonlinearity_df(self, amplitude):
        """DF of ``FRIC(DZ(.))`` (or ``DZ`` alone) at the input amplitude ``amplitude``."""
        p = self.params
        if p.friction_offset != 0:
            return analytic.dead_zone_friction_df(amplitude, p.dead_zone, p.friction_offset)
        return analytic.dead_zone_df(amplitude, p.dead_zone)

    def characteristic_at_dead_zone_input(self, amplitude, frequency):
        """``Phi(Q, w) = 1 - N_sat G BP N + H P(a) N/(jw)``, with ``Q`` the amplitude at the dead
        zone's input and ``a = N Q/w`` (dead zone on the velocity signal; any band-pass loop).
        Where ``N <= 0`` no cycle can exist and ``Phi`` is set to 1."""
        if self.params.dead_zone_position is not DeadZonePosition.VELOCITY:
            raise UnsupportedStructureError("this form needs the dead zone on the velocity signal")
        q = np.asarray(amplitude, dtype=float)
        w = np.asarray(frequency, dtype=float)
        n = self.velocity_nonlinearity_df(q)
        valid = n > 0
        n_safe = np.where(valid, n, 1.0)
        a = n_safe * q / w
        loop = self.bandpass_response(w)
        level = self.params.bandpass_saturation
        if self.params.has_bandpass_loop and np.isfinite(level):
            n_sat = analytic.saturation_df(np.maximum(np.abs(loop) * n_safe * q, 1e-300), level)
        else:
            n_sat = 1.0
        phi = 1.0 - n_sat * loop * n_safe + self.forward_response(w) * self.return_response(a, w) * n_safe / (1j * w)
        return np.where(valid, phi, 1.0 + 0j)

    def output_amplitude(self, dead_zone_input_amplitude, frequency):
        """``a = N(Q) Q/w``: the integrator output's amplitude for a dead-zone input amplitude ``Q``."""
        q = np.asarray(dead_zone_input_amplitude, dtype=float)
        return self.velocity_nonlinearity_df(q) * q / np.asarray(frequency, dtype=float)

    def backlash_df(self, amplitude):
        """Play-operator describing function at the integrator-output amplitude (paper 002 eqs. 4-5)."""
        return analytic.backlash_df(amplitude, self.params.backlash)

    def return_response(self, amplitude, frequency):
        """``P = Gp D_out + K F(a)``, so that the actuator error is ``e = -P x`` (``Gp`` from
        :func:`vehicle_controller_response`: any linear controller and vehicle)."""
        gp = vehicle_controller_response(self.controller, frequency)
        d_out = self.delay_factor(frequency, DelayPosition.OUTPUT)
        return gp * d_out + self.params.feedback_gain * self.backlash_df(amplitude)

    def dead_zone_input_amplitude(self, amplitude, frequency):
        """Amplitude of the dead zone's input when ``x`` has amplitude ``amplitude``."""
        p_ret = self.return_response(amplitude, frequency)
        if self.params.dead_zone_position is DeadZonePosition.ERROR:
            return amplitude * np.abs(p_ret)
        return amplitude * np.abs(self.forward_response(frequency) * p_ret)

    def nonlinearity_df(self, amplitude, frequency):
        """``N(q)`` of the dead zone (and friction offset) at the cycle ``(a, w)``."""
        return self.velocity_nonlinearity_df(self.dead_zone_input_amplitude(amplitude, frequency))

    def open_loop_response(self, amplitude, frequency):
        """``L = H P/(jw)``: everything but the dead zone's gain around the loop."""
        w = np.asarray(frequency, dtype=float)
        return self.forward_response(w) * self.return_response(amplitude, w) / (1j * w)

    def characteristic(self, amplitude, frequency):
        """``Phi(a, w) = 1 + L(jw, a) N(q(a, w))``; zero on a predicted limit cycle."""
        return 1.0 + self.open_loop_response(amplitude, frequency) * self.nonlinearity_df(amplitude, frequency)

    def balance_at(self, amplitude, frequency) -> complex:
        """``Phi`` at a measured cycle (0 when the describing functions balance it exactly).

        Raises
        ------
        AmplitudeBelowDeadZoneError
            When the cycle leaves the dead zone's input inside the dead zone: the dead zone then
            passes nothing and no cycle of that amplitude can be sustained.
        """
        for name, value in (("amplitude", amplitude), ("frequency", frequency)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0 (got {value!r})")
        if self.params.has_bandpass_loop:
            raise UnsupportedStructureError(
                f"{self.params.name}: balance_at is defined without the band-pass loop; use "
                "characteristic_at_dead_zone_input"
            )
        q = float(self.dead_zone_input_amplitude(amplitude, frequency))
        z = self.params.dead_zone
        if q <= z:
            raise AmplitudeBelowDeadZoneError(
                f"amplitude {amplitude:.4g} rad at {frequency:.4g} rad/s puts an amplitude of {q:.4g} on "
                f"the dead zone's input ({self.params.dead_zone_position.value} signal), below its half "
                f"width {z:.4g}: the dead zone passes nothing and {self.params.name} cannot sustain "
                "this cycle"
            )
        return complex(self.characteristic(amplitude, frequency))

    def limit_cycles(self, amplitude_range=None, frequency_range=(0.1, 300.0), **kwargs) -> HarmonicBalanceResult:
        """Every predicted limit cycle; amplitudes are first-harmonic amplitudes of ``delta``.

        Without a band-pass loop the search runs over the output amplitude ``a`` (default range
        1e-6 to 1 rad); with one, over the dead zone's input amplitude ``Q`` (default from the
        dead zone's half width to 10 rad/s) and each cycle reports ``a = N Q/w``.
        """
        label = f"{self.params.name}, {describe_controller(self.controller)}"
        caveat = DF_CAVEAT if self.controller.compensator is None else DF_CAVEAT + "; " + COMPENSATOR_CAVEAT
        if not self.params.has_bandpass_loop:
            return solve_harmonic_balance(
                self.characteristic,
                (1e-6, 1.0) if amplitude_range is None else amplitude_range,
                frequency_range,
                describing_function_at=self.nonlinearity_df,
                label=label,
                caveat=caveat,
                amplitude_name="amplitude of delta (rad)",
                **kwargs,
            )
        z = self.params.dead_zone
        return solve_harmonic_balance(
            self.characteristic_at_dead_zone_input,
            (max(z, 1e-7) * 1.0001, 10.0) if amplitude_range is None else amplitude_range,
            frequency_range,
            describing_function_at=lambda q, w: self.velocity_nonlinearity_df(q),
            label=label + " (band-pass loop at the fundamental)",
            caveat=caveat + "; " + BANDPASS_CAVEAT,
            amplitude_map=self.output_amplitude,
            amplitude_name="amplitude at the dead zone's input",
            **kwargs,
        )


def predict_limit_cycles(params: ActuatorParams, controller: ClosedLoop, **kwargs) -> HarmonicBalanceResult:
    """Limit cycles of ``params`` in the HWIL loop of ``controller`` by harmonic balance.

    ``controller`` is any :class:`tvcid.models.ClosedLoop`: the PD of paper 002 eq. 7, with a compensator
    ``F(s)`` and/or a bending mode, continuous or held at ``sample_rate`` (the hold as its first
    harmonic). See :class:`ActuatorDescribingLoop` for the loop and
    :func:`~tvcid.discovery.describing.harmonic_balance.solve_harmonic_balance` for ``kwargs``.
    """
    return ActuatorDescribingLoop(params, controller).limit_cycles(**kwargs)
