"""The recording format: a CSV of samples plus a JSON sidecar, and its one validating loader.

Format (documented in ``data/README.md``): ``NAME.csv`` with a header row naming at least the
columns ``t, u, delta`` (s, rad, rad; more columns allowed) and ``NAME.json`` beside it with at least
``{"kind": "closed" | "open"}``; closed-loop recordings also need ``kp``, ``kd``, ``mu``, and may
give a ``compensator`` (:meth:`tvcid.models.controllers.TransferFunction.from_dict`) and a ``bending`` mode
(:meth:`tvcid.models.controllers.BendingMode.from_dict`). Every other part of tvcid reads recordings
through :func:`load_recording`.
"""
from __future__ import annotations

import csv
import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .controllers import BendingMode, TransferFunction
from .experiments import ClosedLoop
from .strict_json import jsonable

__all__ = [
    "RecordingError",
    "Recording",
    "load_recording",
    "load_recordings",
    "save_recording",
    "recording_from_trajectory",
    "REQUIRED_COLUMNS",
    "KINDS",
    "TOOL_VERSION",
]

REQUIRED_COLUMNS = ("t", "u", "delta")
KINDS = ("closed", "open")
DEFAULT_UNITS = {"t": "s", "u": "rad", "delta": "rad"}


def _tool_version():
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("tvcid")
    except PackageNotFoundError:  # not installed: running from a checkout
        return "unknown"


TOOL_VERSION = _tool_version()


#: Largest departure of a time step from the typical one, relative to it (timestamp jitter).
UNIFORM_TOLERANCE = 0.05

#: Largest recording read, bytes (~6 million rows of ``t, u, delta``: 100 minutes at 1 kHz). The
#: reader holds the whole table in memory; split longer acquisitions.
MAX_RECORDING_BYTES = 256 * 2**20

#: Largest |u| or |delta| accepted, rad. A nozzle deflects a few degrees; values beyond 0.5 rad
#: (29 degrees) are almost surely degrees written as radians.
MAX_ANGLE = 0.5

#: Units the sidecar may declare for ``u`` and ``delta``, with their factor to radians.
ANGLE_UNITS = {"rad": 1.0, "deg": math.pi / 180.0, "degree": math.pi / 180.0, "degrees": math.pi / 180.0}

#: Sidecar keys tvcid reads or writes. Other keys are kept as free-form provenance, unless they
#: look like a misspelling of one of these (a typo would silently drop a setting).
KNOWN_SIDECAR_KEYS = (
    "kind", "kp", "kd", "mu", "controller_rate", "sample_rate", "units",
    "waveform", "amplitude", "frequency", "start", "offset", "from_rest",
    "hypothesis", "parameters", "seed", "dt", "source", "description", "generator",
    "tool", "tool_version", "theta0", "thetad0", "numbers", "papers", "compensator", "bending",
)


class RecordingError(ValueError):
    """A recording (CSV or sidecar) is malformed; the message names the file and the culprit."""


@dataclass(frozen=True, eq=False)
class Recording:
    """A validated recording.

    Attributes
    ----------
    columns : dict of str -> ndarray
        Every CSV column by name, ``t``, ``u`` and ``delta`` among them.
    meta : dict
        The sidecar, with ``sample_rate`` (Hz) and ``units`` filled in when absent.
    path : Path or None
    """

    columns: dict
    meta: dict = field(default_factory=dict)
    path: Path | None = None

    @property
    def t(self) -> np.ndarray:
        return self.columns["t"]

    @property
    def u(self) -> np.ndarray:
        return self.columns["u"]

    @property
    def delta(self) -> np.ndarray:
        return self.columns["delta"]

    @property
    def kind(self) -> str:
        return self.meta["kind"]

    @property
    def sample_rate(self) -> float:
        return float(self.meta["sample_rate"])

    def experiment(self):
        """The experiment that produced the recording, its time measured from the first sample.

        Closed loop: the :class:`ClosedLoop` of the sidecar. Open loop: the analytic command when
        the sidecar names one (``waveform`` step/square/sine, as tvcid writes them), the record
        starts at t = 0 and the command reproduces every sample of ``u``; square edges then stay
        where they were, where replaying the samples linearly puts each edge half a sample early
        (0.5 ms at 1 kHz, enough to bias an identified delay). Otherwise the command replayed from
        its samples as what it is (:func:`tvcid.models.commands.command_from_samples`: a sampled square
        wave as a square wave with sub-sample edges, a smooth command interpolated).
        """
        from .commands import command_from_samples
        from .experiments import OpenLoop

        if self.kind == "closed":
            return ClosedLoop(
                kp=self.meta["kp"],
                kd=self.meta["kd"],
                mu=self.meta["mu"],
                sample_rate=self.meta.get("controller_rate"),
                compensator=_compensator(self.meta),
                bending=_bending(self.meta),
            )
        waveform = self.meta.get("waveform")
        if waveform in ("step", "square", "sine") and self.t[0] == 0.0:
            keys = ("amplitude", "frequency", "start", "offset", "from_rest")
            try:
                exact = OpenLoop(waveform, **{k: self.meta[k] for k in keys if k in self.meta})
            except (TypeError, ValueError):
                exact = None
            scale = max(float(np.max(np.abs(self.u))), 1e-300)
            if exact is not None and np.allclose(exact.command(self.t), self.u, rtol=0.0, atol=1e-9 * scale):
                return exact
        return command_from_samples(self.t, self.u)

    def window(self, seconds):
        """``(t, delta)`` over the last ``seconds`` (all of it for ``None``)."""
        if seconds is None:
            return self.t, self.delta
        sel = self.t >= self.t[-1] - seconds
        return self.t[sel], self.delta[sel]

    def features(self, window=None, **kwargs):
        """Limit-cycle features of ``delta`` over the last ``window`` seconds."""
        from .cycle_reading import limit_cycle_features

        return limit_cycle_features(*self.window(window), **kwargs)


def _fail(path, message):
    raise RecordingError(f"{path}: {message}")


def _compensator(meta):
    """The sidecar's ``compensator`` as a TransferFunction, or None (ValueError when malformed)."""
    spec = meta.get("compensator")
    return None if spec is None else TransferFunction.from_dict(spec)


def _bending(meta):
    """The sidecar's ``bending`` as a BendingMode, or None (ValueError when malformed)."""
    spec = meta.get("bending")
    return None if spec is None else BendingMode.from_dict(spec)


def _is_number(value):
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _validate_meta(meta, path):
    import difflib

    if not isinstance(meta, dict):
        _fail(path, "sidecar must be a JSON object")
    for key in meta:
        if key in KNOWN_SIDECAR_KEYS:
            continue
        near = difflib.get_close_matches(str(key), KNOWN_SIDECAR_KEYS, n=1, cutoff=0.8)
        if near:
            _fail(path, f"unknown sidecar key '{key}' (did you mean '{near[0]}'?)")
    kind = meta.get("kind")
    if kind not in KINDS:
        _fail(path, f"sidecar 'kind' must be one of {', '.join(KINDS)} (got {kind!r})")
    if kind == "closed":
        for key in ("kp", "kd", "mu"):
            value = meta.get(key)
            if not _is_number(value):
                _fail(path, f"closed-loop sidecar needs a finite number '{key}' (got {value!r})")
        rate = meta.get("controller_rate")
        if rate is not None and not (_is_number(rate) and rate > 0):
            _fail(path, f"sidecar 'controller_rate' must be a positive number of Hz or null (got {rate!r})")
        # checked here so that a bad filter is refused when read, naming its key, not mid-analysis
        for key, build in (("compensator", _compensator), ("bending", _bending)):
            try:
                build(meta)
            except (TypeError, ValueError) as exc:
                _fail(path, f"sidecar '{key}': {' '.join(str(exc).split())}")
    rate = meta.get("sample_rate")
    if rate is not None and not (_is_number(rate) and rate > 0):
        _fail(path, f"sidecar 'sample_rate' must be a positive number of Hz (got {rate!r})")
    units = meta.get("units", {})
    if not isinstance(units, dict):
        _fail(path, f"sidecar 'units' must be an object such as {{\"delta\": \"rad\"}} (got {units!r})")
    if units.get("t", "s") != "s":
        _fail(path, f"sidecar 'units' of 't' must be \"s\" (got {units['t']!r}); convert the time column to seconds")
    for name in ("u", "delta"):
        if name in units and units[name] not in ANGLE_UNITS:
            _fail(path, f"sidecar 'units' of '{name}' must be one of {', '.join(ANGLE_UNITS)} "
                        f"(got {units[name]!r})")


def _validate_columns(columns, path):
    for name in REQUIRED_COLUMNS:
        if name not in columns:
            _fail(path, f"missing column '{name}' (columns: {', '.join(columns) or 'none'})")
    n = columns["t"].size
    if n < 2:
        _fail(path, f"recording is empty or has a single sample ({n} rows)")
    for name, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            _fail(
                path,
                f"column '{name}' holds NaN or infinite values ({bad.size} of them, first at "
                f"data row {bad[0] + 1})",
            )
    steps = np.diff(columns["t"])
    if np.any(steps <= 0):
        k = int(np.flatnonzero(steps <= 0)[0])
        _fail(path, f"column 't' is not strictly increasing (data row {k + 2})")
    # spectra, features and weak-form integrals all assume a uniform grid: refuse, never guess
    typical = float(np.median(steps))
    off = np.abs(steps - typical)
    if off.max() > UNIFORM_TOLERANCE * typical:
        k = int(np.argmax(off))
        _fail(path, f"column 't' is not uniformly sampled: step {steps[k]:.6g} s between data rows "
                    f"{k + 1} and {k + 2} (the typical step is {typical:.6g} s); resample the record "
                    "to a uniform grid or split it at the gap")
    for name in ("u", "delta"):
        peak = int(np.argmax(np.abs(columns[name])))
        if abs(columns[name][peak]) > MAX_ANGLE:
            _fail(path, f"column '{name}' reaches {columns[name][peak]:.6g} at data row {peak + 1}, above "
                        f"{MAX_ANGLE} rad: degrees? Convert to radians or declare "
                        f'"units": {{"{name}": "deg"}} in the sidecar')


def _read_csv(path):
    try:
        size = Path(path).stat().st_size
        if size > MAX_RECORDING_BYTES:
            _fail(path, f"file holds {size:,} bytes, more than the {MAX_RECORDING_BYTES:,} "
                        f"({MAX_RECORDING_BYTES // 2**20} MiB) tvcid reads at once; split the record "
                        "or decimate it")
        raw = Path(path).read_bytes()
    except IsADirectoryError:
        raise RecordingError(f"{path}: is a directory, not a CSV file") from None
    except OSError as exc:
        raise RecordingError(f"{path}: cannot read ({exc.strerror})") from None
    if b"\x00" in raw[:65536]:
        _fail(path, "not a text CSV file (it holds NUL bytes: binary, or UTF-16 text; save it as "
                    "UTF-8 CSV)")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw[: exc.start].count(b"\n") + 1
        _fail(path, f"not UTF-8 text (byte 0x{raw[exc.start]:02x} on line {line}); save it as UTF-8 CSV")
    try:
        rows = list(csv.reader(io.StringIO(text, newline="")))  # quoted names may hold line breaks
    except csv.Error as exc:
        _fail(path, f"not a readable CSV file ({exc})")
    rows = [r for r in rows if r and (r[0].strip() or any(c.strip() for c in r[1:]))]
    if not rows:
        _fail(path, "file is empty")
    header = [h.strip() for h in rows[0]]
    if len(set(header)) != len(header):
        _fail(path, "header repeats a column name")
    for i, row in enumerate(rows[1:]):
        if len(row) != len(header):
            _fail(path, f"data row {i + 1} has {len(row)} fields, the header has {len(header)}")
    try:
        data = np.array(rows[1:], dtype=float).reshape(len(rows) - 1, len(header))
    except ValueError:  # cell by cell, to name the one that is not a number
        data = np.empty((len(rows) - 1, len(header)))
        for i, row in enumerate(rows[1:]):
            for j, cell in enumerate(row):
                try:
                    data[i, j] = float(cell)
                except ValueError:
                    _fail(path, f"data row {i + 1}, column '{header[j]}': not a number ({cell!r})")
    return {name: data[:, j].copy() for j, name in enumerate(header)}


def sidecar_path(path) -> Path:
    """``NAME.json`` beside ``NAME.csv``."""
    return Path(path).with_suffix(".json")


def load_recording(path) -> Recording:
    """Load and validate a recording.

    Checks: the sidecar exists and names a known ``kind`` (and ``kp``, ``kd``, ``mu`` in closed
    loop); the columns ``t, u, delta`` exist, have equal length, hold no NaN; ``t`` is strictly
    increasing. Fills ``sample_rate`` (from the median step) and default ``units`` when absent.

    Raises
    ------
    RecordingError
        Naming the file and what is wrong with it.
    """
    path = Path(path)
    side = sidecar_path(path)
    if not path.exists():
        raise RecordingError(f"{path}: no such recording")
    if not side.exists():
        raise RecordingError(
            f"{path}: missing sidecar {side.name} (a JSON object with at least 'kind')"
        )
    try:
        meta = json.loads(side.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise RecordingError(f"{side}: invalid JSON ({exc.msg} at line {exc.lineno})") from None
    except UnicodeDecodeError as exc:
        raise RecordingError(f"{side}: not UTF-8 text (byte 0x{exc.object[exc.start]:02x}); save the "
                             "sidecar as UTF-8 JSON") from None
    except OSError as exc:
        raise RecordingError(f"{side}: cannot read ({exc.strerror})") from None
    _validate_meta(meta, side)
    columns = _read_csv(path)
    meta = dict(meta)
    units = dict(meta.get("units", {}))
    for name in ("u", "delta"):  # declared degrees are converted here, once, and said so in units
        if name in columns and ANGLE_UNITS.get(units.get(name, "rad"), 1.0) != 1.0:
            columns[name] = columns[name] * ANGLE_UNITS[units[name]]
            units[name] = "rad"
    _validate_columns(columns, path)
    meta["units"] = {**DEFAULT_UNITS, **units}
    measured = 1.0 / float(np.median(np.diff(columns["t"])))
    if meta.get("sample_rate") is None:
        meta["sample_rate"] = measured
    declared = meta["sample_rate"]
    if abs(declared - measured) > UNIFORM_TOLERANCE * measured:
        _fail(path, f"sidecar 'sample_rate' {declared:g} Hz disagrees with column 't' "
                    f"({measured:.6g} Hz from its median step)")
    return Recording(columns=columns, meta=meta, path=path)


def save_recording(path, columns: dict, meta: dict) -> Path:
    """Write ``columns`` to ``path`` (CSV) and ``meta`` to its sidecar, after validating both."""
    path = Path(path)
    columns = {k: np.asarray(v, dtype=float) for k, v in columns.items()}
    _validate_meta(meta, sidecar_path(path))
    _validate_columns(columns, path)
    lengths = {v.size for v in columns.values()}
    if len(lengths) != 1:
        raise RecordingError(f"{path}: columns have unequal lengths {sorted(lengths)}")
    names = list(columns)
    for name in names:  # what the reader would give back differently
        if not isinstance(name, str) or name != name.strip() or not name:
            raise RecordingError(f"{path}: column name {name!r} is empty or has leading/trailing "
                                 "whitespace (the reader strips it)")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as fh:
        csv.writer(fh).writerow(names)
        # numbers need no quoting: written as the csv writer would, without its per-cell cost
        rows = np.column_stack([columns[n] for n in names]).tolist()
        fh.writelines(",".join(map(repr, row)) + "\r\n" for row in rows)
    # strict JSON: an infinite parameter (no saturation) as null, read back by params_from_dict
    text = json.dumps(jsonable(meta, str), indent=2, sort_keys=True, allow_nan=False)
    sidecar_path(path).write_text(text + "\n", encoding="utf-8")
    return path


def recording_from_trajectory(trajectory, seed=None, extra=None):
    """Columns and sidecar for a simulated trajectory (provenance: hypothesis, parameters, seed)."""
    exp = trajectory.experiment
    meta = dict(exp.to_dict())
    if meta["kind"] == "closed":
        meta["controller_rate"] = meta.pop("sample_rate")
    meta.update(
        {
            "source": "simulated",
            "hypothesis": trajectory.params.name,
            "parameters": trajectory.params.to_dict(),
            "seed": trajectory.params.noise_seed if seed is None else seed,
            "dt": trajectory.dt,
            "sample_rate": trajectory.rate,
            "tool": "tvcid",
            "tool_version": TOOL_VERSION,
            "units": {
                "t": "s", "u": "rad", "delta": "rad", "theta": "rad", "x": "rad",
                "y": "rad/s", "w": "rad/s", "backlash": "rad",
            },
        }
    )
    if extra:
        meta.update(extra)
    return trajectory.signals(), meta


def load_recordings(recordings) -> list:
    """Recordings from paths or :class:`Recording` objects, one or several (through
    :func:`load_recording`)."""
    if isinstance(recordings, (str, Path, Recording)):
        recordings = [recordings]
    out = [r if isinstance(r, Recording) else load_recording(r) for r in recordings]
    if not out:
        raise ValueError("no recording given")
    return out
