"""The grammar of actuator structures: every combination of the model's named structural choices.

The general model (:class:`tvcid.models.ActuatorParams`, ``docs/models.md#the-actuator``) has five
structural choices:

* where the dead zone acts: on the error ``e`` or on the velocity-level signal (``DeadZonePosition``);
* where the transport delay acts: at the output, before the integrator, or before the first
  integrator (``DelayPosition``);
* a friction offset ``FRIC`` on or off;
* a play-operator backlash in the feedback on or off;
* the positive band-pass loop (with its saturation) on or off.

That is 2 x 3 x 2 x 2 x 2 = 48 combinations. :func:`structure_space` returns the ones kept and, for
each one pruned, the reason. One rule prunes (12 combinations, 36 kept):

* **friction offset with the dead zone on the error.** Paper 001 defines the offset on the output of
  the velocity dead zone, ``w = FRIC(DZ_z(v + p))``; while the actuator moves this is
  ``w = v + p - (z - off) sign(v)``, so friction and dead zone act as one threshold. Without a dead
  band on the velocity signal, ``FRIC(v)`` switches ``x'`` by ``2 off`` at every zero crossing of a
  smooth velocity: a sliding mode that no paper proposes and that a fixed-step simulation resolves
  only as chatter at the step size.

Structures are nested: a structure without backlash (friction, band-pass loop) is the one with it at
``backlash = 0`` (``friction_offset = 0``, ``bandpass_gain = 0``). Nested structures that fit alike
are merged by the discovery (:mod:`tvcid.discovery.structure`), which states it in its output.

Every structure maps to ``tvcid.models`` exactly: :meth:`Structure.to_params` returns the
:class:`~tvcid.models.ActuatorParams` with the structural enums set and the absent components zeroed, and
:meth:`Structure.of_params` reads the structure of any parameter object.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

from .hypotheses import ActuatorParams, DeadZonePosition, DelayPosition

__all__ = [
    "Structure",
    "structure_space",
    "all_structures",
    "UnknownStructureError",
    "COMPONENT_FIELDS",
    "STRUCTURE_FIELDS",
    "CHOICES",
    "shared_choices",
]

#: The parameter fields each optional component owns (zeroed when the component is absent).
COMPONENT_FIELDS = {
    "friction": ("friction_offset",),
    "backlash": ("backlash",),
    "bandpass": ("bandpass_gain", "bandpass_saturation"),
}
#: Fields every structure has (the linear block, the dead zone, the delay).
CORE_FIELDS = ("gain", "damping", "stiffness", "feedback_gain", "dead_zone", "delay")
#: Fields that are structural choices rather than parameters.
STRUCTURE_FIELDS = ("dead_zone_position", "delay_position")

_DZ_SHORT = {DeadZonePosition.ERROR: "dz_error", DeadZonePosition.VELOCITY: "dz_velocity"}
_DELAY_SHORT = {
    DelayPosition.OUTPUT: "delay_output",
    DelayPosition.BEFORE_INTEGRATOR: "delay_before_integrator",
    DelayPosition.BEFORE_FIRST_INTEGRATOR: "delay_before_first_integrator",
}


class UnknownStructureError(ValueError):
    """A structure name that the grammar cannot parse."""


@dataclass(frozen=True, order=True)
class Structure:
    """One combination of the structural choices.

    Parameters
    ----------
    dead_zone_position : DeadZonePosition or str
    delay_position : DelayPosition or str
    friction : bool
        Friction offset ``FRIC(q) = q + off sign(q)`` present.
    backlash : bool
        Play operator ``play_r`` in the feedback present.
    bandpass : bool
        Positive band-pass loop ``p = sat_s(G BP(w))`` present.
    """

    dead_zone_position: DeadZonePosition
    delay_position: DelayPosition
    friction: bool
    backlash: bool
    bandpass: bool

    def __post_init__(self):
        object.__setattr__(self, "dead_zone_position", DeadZonePosition(self.dead_zone_position))
        object.__setattr__(self, "delay_position", DelayPosition(self.delay_position))
        for name in ("friction", "backlash", "bandpass"):
            object.__setattr__(self, name, bool(getattr(self, name)))

    # -- names -----------------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """``dz_velocity+delay_before_first_integrator+friction+backlash+bandpass`` style name."""
        parts = [_DZ_SHORT[self.dead_zone_position], _DELAY_SHORT[self.delay_position]]
        parts += [c for c in ("friction", "backlash", "bandpass") if getattr(self, c)]
        return "+".join(parts)

    def __str__(self):
        return self.name

    @classmethod
    def parse(cls, name: str) -> "Structure":
        """Inverse of :attr:`name`."""
        parts = str(name).strip().split("+")
        dz = {v: k for k, v in _DZ_SHORT.items()}
        dl = {v: k for k, v in _DELAY_SHORT.items()}
        if len(parts) < 2 or parts[0] not in dz or parts[1] not in dl:
            raise UnknownStructureError(
                f"cannot parse structure {name!r}: expected 'dz_error|dz_velocity' + "
                "'delay_output|delay_before_integrator|delay_before_first_integrator' "
                "then any of '+friction', '+backlash', '+bandpass'"
            )
        extra = set(parts[2:])
        unknown = extra - {"friction", "backlash", "bandpass"}
        if unknown:
            raise UnknownStructureError(f"unknown component(s) {', '.join(sorted(unknown))} in {name!r}")
        return cls(dz[parts[0]], dl[parts[1]], "friction" in extra, "backlash" in extra,
                   "bandpass" in extra)

    # -- parameters -------------------------------------------------------------------------------
    @property
    def components(self) -> tuple:
        """Names of the optional components present."""
        return tuple(c for c in ("friction", "backlash", "bandpass") if getattr(self, c))

    def parameter_names(self) -> tuple:
        """The ``ActuatorParams`` fields this structure has as free parameters."""
        names = list(CORE_FIELDS)
        for comp in self.components:
            names += COMPONENT_FIELDS[comp]
        return tuple(names)

    def absent_fields(self) -> dict:
        """Values of the fields of absent components (what 'off' means in ``tvcid.models``)."""
        out = {}
        if not self.friction:
            out["friction_offset"] = 0.0
        if not self.backlash:
            out["backlash"] = 0.0
        if not self.bandpass:
            out["bandpass_gain"] = 0.0
            out["bandpass_saturation"] = math.inf
        return out

    def to_params(self, base: ActuatorParams | None = None, **values) -> ActuatorParams:
        """The parameter object of this structure.

        ``base`` supplies the fields not given in ``values`` (initial conditions, band of the
        band-pass filter, ...); the structural enums and the fields of absent components are set
        from the structure whatever ``base`` and ``values`` hold.
        """
        fields = dict(base.to_dict()) if base is not None else {}
        fields.update(values)
        fields.update(self.absent_fields())
        fields["dead_zone_position"] = self.dead_zone_position
        fields["delay_position"] = self.delay_position
        missing = [n for n in CORE_FIELDS if n not in fields]
        if missing:
            raise ValueError(f"structure {self.name} needs value(s) for {', '.join(missing)}")
        return ActuatorParams(**fields)

    @classmethod
    def of_params(cls, params: ActuatorParams) -> "Structure":
        """The structure of a parameter object (a component is present when its value is not 0)."""
        return cls(
            params.dead_zone_position,
            params.delay_position,
            friction=params.friction_offset != 0.0,
            backlash=params.backlash > 0.0,
            bandpass=params.bandpass_gain > 0.0,
        )

    def without(self, component: str) -> "Structure":
        """The nested structure with ``component`` removed."""
        if component not in COMPONENT_FIELDS:
            raise ValueError(f"unknown component {component!r}")
        return Structure(self.dead_zone_position, self.delay_position,
                         **{c: getattr(self, c) and c != component for c in COMPONENT_FIELDS})

    def with_(self, component: str) -> "Structure":
        """The structure with ``component`` added."""
        if component not in COMPONENT_FIELDS:
            raise ValueError(f"unknown component {component!r}")
        return Structure(self.dead_zone_position, self.delay_position,
                         **{c: getattr(self, c) or c == component for c in COMPONENT_FIELDS})

    def to_dict(self) -> dict:
        return {"name": self.name, "dead_zone_position": self.dead_zone_position.value,
                "delay_position": self.delay_position.value, "friction": self.friction,
                "backlash": self.backlash, "bandpass": self.bandpass}


#: The five structural choices, as :meth:`Structure.to_dict` names them.
CHOICES = ("dead_zone_position", "delay_position", "friction", "backlash", "bandpass")


def shared_choices(structures) -> dict:
    """What a set of structures agrees on: choice -> its common value, or ``None`` where they differ.

    Given the structures recordings cannot tell apart, this is what the recordings decide (e.g.
    the dead zone on the velocity signal and a band-pass loop) and what they leave open (e.g.
    the delay before the first integrator or before the integrator).

    Raises
    ------
    ValueError
        For an empty set (it decides nothing and agrees on everything).
    """
    dicts = [Structure.parse(s).to_dict() if isinstance(s, str) else s.to_dict() for s in structures]
    if not dicts:
        raise ValueError("shared_choices needs at least one structure")
    return {c: dicts[0][c] if all(d[c] == dicts[0][c] for d in dicts) else None for c in CHOICES}


#: Why a combination is pruned (see the module docstring).
FRICTION_NEEDS_VELOCITY_DEAD_ZONE = (
    "friction offset needs the dead zone on the velocity signal: paper 001 defines it on the "
    "velocity dead zone's output, where it merges with the threshold (z - off); without a dead band "
    "FRIC(v) switches x' by 2 off at every zero crossing of a smooth velocity (a sliding mode)"
)


def all_structures() -> list:
    """All 48 combinations of the structural choices."""
    return [
        Structure(dz, dl, fr, bl, bp)
        for dz, dl, fr, bl, bp in itertools.product(
            DeadZonePosition, DelayPosition, (False, True), (False, True), (False, True)
        )
    ]


def prune_reason(structure: Structure) -> str | None:
    """Why ``structure`` is pruned from the search, or ``None`` when it is kept."""
    if structure.friction and structure.dead_zone_position is DeadZonePosition.ERROR:
        return FRICTION_NEEDS_VELOCITY_DEAD_ZONE
    return None


def structure_space(fixed: dict | None = None):
    """The kept structures and the pruned ones with their reasons.

    Parameters
    ----------
    fixed : dict, optional
        Known parts: ``dead_zone_position``/``delay_position`` restrict the space to that choice;
        ``friction_offset``/``backlash``/``bandpass_gain`` fixed at 0 remove the component, fixed at
        a non-zero value require it.

    Returns
    -------
    kept : list of Structure
    pruned : dict Structure -> str
    """
    fixed = dict(fixed or {})
    kept, pruned = [], {}
    for s in all_structures():
        reason = prune_reason(s)
        if reason is None:
            reason = _conflict_with_fixed(s, fixed)
        if reason is None:
            kept.append(s)
        else:
            pruned[s] = reason
    return kept, pruned


def _conflict_with_fixed(s: Structure, fixed: dict) -> str | None:
    if "dead_zone_position" in fixed and DeadZonePosition(fixed["dead_zone_position"]) != s.dead_zone_position:
        return f"dead_zone_position fixed to {DeadZonePosition(fixed['dead_zone_position']).value}"
    if "delay_position" in fixed and DelayPosition(fixed["delay_position"]) != s.delay_position:
        return f"delay_position fixed to {DelayPosition(fixed['delay_position']).value}"
    for comp, fields in COMPONENT_FIELDS.items():
        key = fields[0]
        if key in fixed:
            present = float(fixed[key]) != 0.0
            if present != getattr(s, comp):
                return f"{key} fixed to {fixed[key]} ({comp} {'present' if present else 'absent'})"
    return None
