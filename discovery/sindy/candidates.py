"""Structure proposals: a fitted form, its terms, thresholds and inclusion probabilities.

Each proposal converts into a :class:`tvcid.models.ActuatorParams`, so that it can be simulated as a
full closed-loop model (:mod:`tvcid.discovery.sindy.ranking`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from tvcid.models.hypotheses import ActuatorParams, DeadZonePosition, DelayPosition

__all__ = ["Candidate"]


@dataclass(eq=False)
class Candidate:
    """One fitted structure proposal.

    Attributes
    ----------
    form : str
        Name of its :class:`tvcid.discovery.sindy.forms.StructureForm`.
    terms : dict of str -> float
        Selected library terms and coefficients of the weak equation
        ``delta''' = sum_j coef_j * term_j`` (terms not selected are absent).
    thresholds : dict of str -> float
        The nonlinear parameters found by the scan (``dead_zone``, ``backlash``, ``delay``, ...).
    inclusion : dict of str -> float
        Fraction of bootstrap fits in which each term (and each threshold element: ``backlash``,
        ``dead_zone``) was selected.
    weak_residual : float
        Residual of the weak system over the target's norm.
    criterion : float
        Information criterion of the weak fit (lower is better).
    params : dict
        The block parameters recovered (``gain`` K1, ``damping`` K2, ``stiffness`` K3,
        ``feedback_gain`` K, ``friction_offset``, ...), as :class:`tvcid.models.ActuatorParams` fields.
    score : float or None
        Simulation score from :func:`tvcid.discovery.sindy.ranking.rank_by_simulation` (lower is better).
    """

    form: str
    terms: dict
    thresholds: dict
    inclusion: dict
    weak_residual: float
    criterion: float
    params: dict
    score: float | None = None
    score_details: dict = field(default_factory=dict)

    @property
    def static_gain(self) -> float:
        """``K1/K3``: static gain of the second-order block, pinned even by limit-cycle data."""
        stiffness = self.params.get("stiffness", 0.0)
        return self.params["gain"] / stiffness if stiffness else math.nan

    def to_params(self, **overrides) -> ActuatorParams:
        """The proposal as a :class:`tvcid.models.ActuatorParams` (a ``custom`` hypothesis).

        ``overrides`` set fields the fit does not determine, e.g. ``x0`` for a closed-loop run.

        Raises
        ------
        ValueError
            When the fitted block is not a valid model (e.g. a non-positive gain), naming the field.
        """
        p = dict(self.params)
        velocity = p.pop("dead_zone_on") == "velocity"
        inside = p.pop("delay_inside_loop")
        fields = dict(
            gain=p["gain"],
            damping=p["damping"],
            stiffness=p["stiffness"],
            feedback_gain=p["feedback_gain"],
            dead_zone=p["dead_zone"],
            dead_zone_position=DeadZonePosition.VELOCITY if velocity else DeadZonePosition.ERROR,
            backlash=p["backlash"],
            delay=p["delay"],
            delay_position=DelayPosition.BEFORE_INTEGRATOR if inside else DelayPosition.OUTPUT,
            friction_offset=p["friction_offset"],
            bandpass_gain=p.get("bandpass_gain", 0.0),
            bandpass_saturation=p.get("bandpass_saturation", math.inf),
        )
        fields.update(overrides)
        return ActuatorParams(**fields)

    def to_dict(self) -> dict:
        """JSON-ready summary (the CLI's ``candidates`` entries)."""
        return {
            "form": self.form,
            "terms": dict(self.terms),
            "thresholds": dict(self.thresholds),
            "inclusion": dict(self.inclusion),
            "score": self.score if self.score is None or math.isfinite(self.score) else None,
            "score_details": dict(self.score_details),
            "weak_residual": self.weak_residual,
            "criterion": self.criterion,
            "params": {k: (v if not isinstance(v, float) or math.isfinite(v) else None)
                       for k, v in self.params.items()},
            "static_gain": self.static_gain if math.isfinite(self.static_gain) else None,
        }
