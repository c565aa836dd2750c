"""The quantities a set's report prints, from one parameter set or arrays of draws.

* :func:`member_quantities` -- the dead zone (in its place's units), the delay, each optional
  component's quantity where the member has it, the velocity dead zone's moving threshold, and
  the linear loop's DC gain and bandwidth (:func:`linear_block_dc_gain_and_bandwidth`);
* :data:`QUANTITY_UNITS`, :data:`COMPONENT_QUANTITIES` -- their units, and which belongs to
  which component.

Pure functions of :class:`tvcid.models.ActuatorParams` fields; the calibration's step error and
the set's posterior (``tvcid.discovery``) both read them.
"""
from __future__ import annotations

import numpy as np

__all__ = ["member_quantities", "linear_block_dc_gain_and_bandwidth", "QUANTITY_UNITS",
           "COMPONENT_QUANTITIES"]

#: Unit of each combined quantity (the dead zone's depends on its place).
QUANTITY_UNITS = {
    "dead_zone[error]": "rad", "dead_zone[velocity]": "rad/s", "threshold": "rad/s",
    "backlash": "rad", "friction_offset": "rad/s", "bandpass_gain": "1", "delay": "s",
    "dc_gain": "rad/rad", "bandwidth": "rad/s",
}
#: The quantity of each optional component (:data:`tvcid.models.structures.COMPONENT_FIELDS`).
COMPONENT_QUANTITIES = {"friction": "friction_offset", "backlash": "backlash",
                        "bandpass": "bandpass_gain"}
#: Frequencies (rad/s) on which the linear block's -3 dB point is found.
_OMEGA = np.logspace(-1, 4.5, 1200)


def linear_block_dc_gain_and_bandwidth(gain, damping, stiffness, feedback_gain):
    """DC gain (``1/K``) and -3 dB bandwidth (rad/s) of the actuator's linear position loop
    ``K1 / (s^3 + K2 s^2 + K3 s + K K1)`` (docs/models.md#the-linear-block-and-the-papers-a-b-c),
    for arrays of parameters; the bandwidth is ``nan`` where the response never falls 3 dB below
    its DC value within 10^4.5 rad/s."""
    k1, k2, k3, k = (np.atleast_1d(np.asarray(v, dtype=float)) for v in
                     (gain, damping, stiffness, feedback_gain))
    s = 1j * _OMEGA[None, :]
    h = k1[:, None] / (s ** 3 + k2[:, None] * s ** 2 + k3[:, None] * s + (k * k1)[:, None])
    ratio = np.abs(h) * k[:, None]  # |H| / DC gain
    below = ratio < 1 / np.sqrt(2)
    bandwidth = np.full(k1.shape, np.nan)
    for i in np.flatnonzero(below.any(axis=1)):
        j = int(np.argmax(below[i]))
        if j == 0:
            bandwidth[i] = _OMEGA[0]
            continue
        # interpolate the crossing in log frequency
        r0, r1 = ratio[i, j - 1], ratio[i, j]
        f = (r0 - 1 / np.sqrt(2)) / (r0 - r1)
        bandwidth[i] = float(np.exp(np.log(_OMEGA[j - 1]) + f * np.log(_OMEGA[j] / _OMEGA[j - 1])))
    return 1.0 / k, bandwidth


def member_quantities(params: dict, draws: dict) -> dict:
    """The combined quantities of one member: its fitted ``params`` (a dict of
    :class:`tvcid.models.ActuatorParams` fields) with the sampled fields replaced by ``draws`` (name ->
    array, natural units); every array the same length. A component's quantity is there only
    where the member has the component (sampled, or nonzero in ``params``)."""
    n = len(next(iter(draws.values()))) if draws else 1
    value = {name: np.broadcast_to(np.asarray(draws.get(name, params.get(name, 0.0)), dtype=float), (n,))
             for name in ("gain", "damping", "stiffness", "feedback_gain", "dead_zone",
                          "friction_offset", "backlash", "bandpass_gain", "delay")}
    position = str(params.get("dead_zone_position", "error"))
    out = {f"dead_zone[{position}]": value["dead_zone"], "delay": value["delay"]}
    for name in COMPONENT_QUANTITIES.values():
        if name in draws or float(params.get(name, 0.0) or 0.0) != 0.0:
            out[name] = value[name]
    if position == "velocity":
        out["threshold"] = value["dead_zone"] - value["friction_offset"]
    dc, bw = linear_block_dc_gain_and_bandwidth(value["gain"], value["damping"],
                                                value["stiffness"], value["feedback_gain"])
    out["dc_gain"], out["bandwidth"] = dc, bw
    return {k: np.array(v, dtype=float) for k, v in out.items()}
