"""The result of ``tvcid discover``: :class:`DiscoveryResult`, its run record
(:class:`tvcid.run_record.RunRecord`, the content of ``discovery.json``) with its readers, its
report and its plot."""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tvcid.models.strict_json import jsonable, write_json, write_text_atomic

from .run_record import RunRecord

__all__ = ["DiscoveryResult"]


def _json_default(v):
    """Enums as their value, anything else as its text."""
    if hasattr(v, "value"):
        return v.value
    return str(v)


@dataclass
class DiscoveryResult:
    """What :func:`discover` found: its run record, with its readers.

    Attributes
    ----------
    record : tvcid.run_record.RunRecord
        The ranking (``structures``, best first), the set the recordings cannot tell apart
        (``indistinguishable``), the structural choices they decide (``decided``), the sensor
        offsets and noise, the next test, the posterior over the set (``set_posterior``: each
        calibrated member's and their combination), the winner's alone (``posterior``) and
        what each stage cost.
    out : Path or None
        The directory it was written to.
    """

    record: RunRecord
    out: Path | None = None

    @classmethod
    def from_dict(cls, summary, out=None) -> "DiscoveryResult":
        """A result from ``discovery.json``'s content (:meth:`RunRecord.from_dict`)."""
        return cls(RunRecord.from_dict(summary), out)

    @property
    def summary(self) -> dict:
        """``discovery.json``'s content (:meth:`RunRecord.to_dict`; its values are the
        record's own)."""
        return self.record.to_dict()

    @classmethod
    def load(cls, path) -> "DiscoveryResult":
        """A result from its ``discovery.json`` (or the directory holding it)."""
        path = Path(path)
        if path.is_dir():
            path = path / "discovery.json"
        try:
            summary = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: not a discovery.json ({exc})") from None
        try:
            return cls.from_dict(summary, path.parent)
        except ValueError as exc:
            raise ValueError(f"{path}: {exc}") from None

    @property
    def best(self) -> dict:
        """The winner's row: ``structure``, ``score``, ``params``, ``coordinate_sd``, ..."""
        return self.record.structures[0]

    @property
    def indistinguishable(self) -> list:
        """Names of the structures the recordings cannot tell from the winner (merged ones too)."""
        return list(self.record.indistinguishable)

    @property
    def decided(self) -> dict:
        """Each structural choice: its value where the set agrees on it, else ``None``."""
        return dict(self.record.decided)

    @property
    def posterior(self):
        """The MCMC summary of the winner alone (``parameters``: q05, q50, q95 each), or
        ``None``; the set's combined posterior is :attr:`set_posterior`."""
        return self.record.posterior

    @property
    def set_posterior(self):
        """The posterior over the set the recordings leave open, or ``None`` (no MCMC).

        ``quantities`` maps each combined quantity (``delay``, ``dead_zone[velocity]``,
        ``dc_gain``, ...) to its median and 90 % interval (``q50``, ``q05``, ``q95``), unit and
        verdicts; ``members`` holds each calibrated structure's own posterior.
        """
        return self.record.set_posterior

    def interval(self, name, level=0.90) -> tuple:
        """The combined 90 % interval ``(q05, q95)`` of quantity ``name`` over the set.

        Parameters
        ----------
        name : str
            A key of ``set_posterior["quantities"]``: ``"delay"``, ``"dead_zone[velocity]"``,
            ``"dc_gain"``, ...
        level : float
            The interval's probability; the summary stores the 90 % interval only.

        Returns
        -------
        tuple of float
            ``(q05, q95)``; NaN where the summary holds no finite value.

        Raises
        ------
        ValueError
            No set posterior (a run with ``mcmc=False``), an unknown quantity (the message names
            those there are), or a level other than 0.90.
        """
        if not math.isclose(level, 0.90):
            raise ValueError(f"interval level {level!r}: the summary stores the 90 % interval "
                             "(q05, q95) only")
        quantities = (self.set_posterior or {}).get("quantities")
        if not quantities:
            raise ValueError("no set posterior: the run stopped after the ranking (run discover "
                             "with its MCMC to calibrate the set)")
        if name in (self.set_posterior.get("left_open_uncalibrated") or ()):
            raise ValueError(f"{name}: the set leaves its component open and no member with it "
                             "could be calibrated, so no interval is printed")
        if name not in quantities:
            raise ValueError(f"unknown quantity {name!r}; the set's posterior has "
                             f"{', '.join(quantities)}")
        # a fresh run's summary holds non-finite values as such, one read back as None
        ends = (quantities[name][k] for k in ("q05", "q95"))
        return tuple(float(v) if v is not None and math.isfinite(v) else math.nan for v in ends)

    def to_dict(self) -> dict:
        """``discovery.json``'s content as strict JSON values (non-finite numbers as ``None``)."""
        return jsonable(self.record.to_dict(), _json_default)

    def report(self) -> str:
        """``report.md``'s text (:func:`tvcid.report.discovery_report`)."""
        from .report import discovery_report

        return discovery_report(self.to_dict())

    def save(self, out=None) -> Path:
        """Write ``discovery.json`` and ``report.md`` into ``out`` (default: where it came from)."""
        out = Path(out if out is not None else self.out)
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / "discovery.json", self.record.to_dict(), default=_json_default)
        write_text_atomic(out / "report.md", self.report())
        self.out = out
        return out

    def plot(self, ax=None):
        """The ranking: each structure's out-of-sample score, the set the recordings cannot tell
        apart in colour; returns the axes."""
        import matplotlib.pyplot as plt

        rows = self.record.structures[:20]
        if ax is None:
            ax = plt.subplots(figsize=(7, 0.3 * len(rows) + 1.2))[1]
        scores = [s["score"] if s["score"] is not None else np.nan for s in rows]
        colours = ["C0" if s["indistinguishable_from_best"] else "0.7" for s in rows]
        y = np.arange(len(rows))[::-1]
        ax.barh(y, scores, color=colours)
        ax.set_yticks(y, [s["structure"] for s in rows], fontsize=7)
        ax.set_xscale("log")
        ax.set_xlabel(f"score ({rows[0]['criterion']}); in colour: the set left open")
        return ax
