"""What a calibration's checkpoint holds of its start, restored on resuming.

A part of :class:`tvcid.discovery.calibration.calibration.Calibration` (as
:class:`.importance_stage.ImportanceStage` is): a resumed run must evaluate the same posterior
as the run that wrote the checkpoint, so everything the start decided is read back before any
sampling: the records that fell back to their features, the steps the start's step check chose,
the solver corrections, the transients chosen, each record's start imprint and the discrepancy
factors. A checkpoint of a different set-up is refused in one line naming what differs.
"""
from __future__ import annotations

import json

from .backend import H5_GROUP

__all__ = ["StartRestore"]


class StartRestore:
    """Restoring a calibration's start from its checkpoint."""

    def _restore_start(self, backend, path, config):
        """Apply what the checkpoint at ``path`` (opened through ``backend``) stored of the
        start, where it was written with the same set-up ``config`` (JSON); raise
        ``ValueError`` where it was written with another."""
        with backend.open("r") as f:
            old = f[H5_GROUP].attrs.get("config") if H5_GROUP in f else None
            stored = f[H5_GROUP].attrs.get("inflation") if H5_GROUP in f else None
            transient = ({k: v[()] for k, v in f[H5_GROUP]["transient_var"].items()}
                         if H5_GROUP in f and "transient_var" in f[H5_GROUP] else None)
            step_check = f[H5_GROUP].attrs.get("step_check_at") if H5_GROUP in f else None
            solver = ({k: v[()] for k, v in f[H5_GROUP]["solver_correction"].items()}
                      if H5_GROUP in f and "solver_correction" in f[H5_GROUP] else None)
            solver_points = (f[H5_GROUP].attrs.get("solver_check_points")
                             if H5_GROUP in f else None)
            chosen = f[H5_GROUP].attrs.get("transients") if H5_GROUP in f else None
            fallbacks = f[H5_GROUP].attrs.get("fallbacks") if H5_GROUP in f else None
        if fallbacks is not None and old == config:  # resuming: the records that fell back
            names = [t.name for t in self.terms_]
            for name, reason in json.loads(fallbacks).items():
                if name not in self.fallbacks_:
                    self._fall_back(names.index(name), reason)
        if step_check is not None and old == config:  # resuming: the steps of the start
            self._refine_steps_at(json.loads(step_check), save=False)
        if solver is not None and old == config:  # resuming: the start's solver corrections
            for term in self.terms_:
                if term.name in solver and hasattr(term, "set_solver_correction"):
                    term.set_solver_correction(*solver[term.name])
            self.solver_check_points_ = json.loads(solver_points) if solver_points else None
        if chosen is not None and old == config:  # resuming: the transients chosen
            self.transients_ = json.loads(chosen)
            for term in self.terms_:
                if term.name in self.transients_:
                    term.set_transient(self.transients_[term.name])
        if transient is not None and old == config:  # resuming: the start's imprint
            for term in self.terms_:
                if term.name in transient:
                    term.set_transient_variance(transient[term.name])
        if stored is not None and old == config:  # resuming: the factors of the start
            self.inflation_ = [float(v) for v in json.loads(stored)]
            for term, value in zip(self.terms_, self.inflation_):
                term.inflation = value
        if old is not None and old != config:
            was, now = json.loads(old), json.loads(config)
            changed = sorted(k for k in set(was) | set(now) if was.get(k) != now.get(k))
            diff = "; ".join(f"{k}: {was.get(k)!r} -> {now.get(k)!r}" for k in changed)
            raise ValueError(
                f"{path} holds a run with a different set-up ({diff}); it is kept: choose "
                "another output directory, or delete it to start again")
