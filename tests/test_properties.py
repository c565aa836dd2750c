"""Property-based tests (``hypothesis``): what must hold for every input in range, not just a few.

Every property runs with ``derandomize=True`` (the same examples every run) and
an explicit example budget; ``deadline=None`` because the first call of a numba kernel loads it.

Properties
----------
Recording format (:mod:`tvcid.models.recording`)
    * Any finite table round-trips bit for bit through :func:`save_recording` and
      :func:`load_recording`: 2 to 60 rows on a uniform time grid (start within +-1e4 s, step
      1e-5 to 1 s, each timestamp jittered by up to 1 % of the step, inside the reader's
      ``UNIFORM_TOLERANCE``), ``u`` and ``delta`` within +-0.4 rad (the reader refuses more than
      0.5 rad as probable degrees), any number of extra columns of any finite value whose names
      need CSV quoting (commas, quotes) or are not ASCII; the sidecar comes back as written plus
      the filled-in ``sample_rate`` (1 / median step) and default ``units``.
    * Any table holding NaN or an infinity (written as ``nan``, ``inf``, ``-Infinity``, ...) in
      any cells is refused by the reader with a :class:`RecordingError` naming the first such
      column in header order, how many of its cells are bad and the data row (1-based) of the
      first; :func:`save_recording` refuses the same table with the same message and writes
      nothing.

Simulator (:func:`tvcid.models.simulate`, :func:`tvcid.models.simulate_batch`)
    For parameters in their declared ranges the simulator returns a trajectory whose every signal
    is finite, or raises :class:`tvcid.models.SimulationDiverged`; never any other exception. The
    ranges are those of the seeded scenario generator (:mod:`tvcid.studies.benchmarks.scenarios`): its own
    :func:`draw_truth` and :func:`draw_design` are called with a stand-in random generator whose
    every draw is made by ``hypothesis`` within the bounds the generator asks for, so the ranges
    are the generator's, not copies (every kept structure of :func:`tvcid.models.structures.structure_space`,
    every controller setting, controller held at 200 Hz or continuous, acquisition at 200 Hz or
    1 kHz, open-loop squares and sines, plus a step of the same amplitude). The four paper
    hypotheses (:func:`tvcid.models.hypothesis`) are run with their structure's parameters drawn the
    same way and initial conditions within the basin study's ranges
    (:class:`tvcid.studies.h3_initial_conditions.Config`). Runs last 1 to 3 s. A returned trajectory
    also keeps ``|x|`` and ``|theta|`` within the divergence bound, its backlash output within
    ``r`` of ``x``, its time grid at the requested rate, and in open loop ``u`` equal to the
    command and ``theta = 0``. :func:`simulate_batch` on the same runs flags exactly the runs
    that :func:`simulate` reports diverged and returns the same signals for the others.

Limit-cycle features of a pure sinusoid (:func:`tvcid.models.limit_cycle_features`)
    ``x = c + A sin(2 pi f t + phi)``, ``A`` in [1e-4, 0.1] rad, ``f`` in [0.5, 20] Hz, sampled at
    ``fs`` in [200, 1000] Hz (10 to 2000 samples a period) over 3.5 to 12 periods (enough for two
    whole periods between the first and last detected upward crossing at any phase), any phase,
    offset ``c`` within +-0.05 rad, any start time. With ``N`` the number of samples in the whole
    periods used (``n_periods * fs / f``, at least 20) and ``m`` the record length in periods:

    * amplitude (half peak-to-peak of the samples): ``A cos(pi f / fs) <= amplitude <= A``, the
      exact bound for samples within half a step of each peak (4.9 % at 20 Hz sampled at 200 Hz,
      0.2 % at 20 Hz sampled at 1 kHz); amplitude drift within ``(1 - cos)/cos`` of the same;
    * frequency: relative error at most ``0.05 / N`` (0.25 % in the worst case, 10 samples a
      period over 2 periods; 0.0025 % for 1 Hz at 1 kHz over 2 periods); period jitter below 0.5 %;
    * mean: within ``A / N`` of ``c``;
    * first harmonic: within ``2 / N`` of ``A`` (relative); harmonics 2.. below the Nyquist
      frequency at most ``A / N`` (harmonics above it are aliases and are not checked);
    * whole periods used: ``floor(m) - 2 <= n_periods <= floor(m)``.

Nonlinearities (:mod:`tvcid.models.nonlinearities`)
    Dead zone ``DZ_z``: odd; zero inside the band, ``|q| - z`` in magnitude with the sign of ``q``
    outside; nondecreasing; slope 1 on each side beyond the band and 1-Lipschitz everywhere;
    positively homogeneous (``DZ_cz(c q) = c DZ_z(q)``); ``DZ_z + sat_z`` is the identity;
    ``DZ_z1 o DZ_z2 = DZ_(z1+z2)``; ``DZ_0`` is the identity; the numba kernel's scalar dead zone
    equals it. Play operator ``P_r`` (initial memory ``b0``): odd
    (``P_r(-x; -b0) = -P_r(x; b0)``); positively homogeneous; its output stays within ``r`` of the
    input at every sample; once the input has moved by ``2 r`` (some earlier sample ``x_i`` with
    ``x_i - r >= x_k + r`` or ``x_i + r <= x_k - r``) the output no longer depends on ``b0``;
    rate independent (repeating samples, or inserting points between two samples on the segment
    joining them, leaves the output at the original samples unchanged); ``P_0`` is the identity;
    ``P_r2(P_r1(x; b1); b2) = P_(r1+r2)(x; b2)`` when ``|b2 - b1| <= r2``; ``play_step``
    iterated is :func:`play_operator`.

Approximate equalities (homogeneity, composition) allow 1e-12 of the operands' magnitude
(floating-point rounding); the others are exact.
"""
from __future__ import annotations

import csv
import json
import math
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import Phase, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from tvcid.models import (
    HYPOTHESES,
    ClosedLoop,
    OpenLoop,
    SimulationDiverged,
    limit_cycle_features,
    simulate,
    simulate_batch,
)
from tvcid.models import hypothesis as make_hypothesis
from tvcid.models.kernel import _dead_zone as kernel_dead_zone
from tvcid.models.nonlinearities import dead_zone, play_operator, play_step, saturation
from tvcid.models.recording import (
    DEFAULT_UNITS,
    RecordingError,
    load_recording,
    save_recording,
    sidecar_path,
)
from tvcid.models.simulate import DEFAULT_BOUND, DEFAULT_DT
from tvcid.models.structures import Structure
from tvcid.studies.benchmarks.scenarios import draw_design, draw_truth
from tvcid.studies.h3_initial_conditions import Config as BasinConfig

FINITE = dict(allow_nan=False, allow_infinity=False)


def _settings(n):
    # no "explain" phase: on a failure it reruns the simulator thousands of times
    return settings(max_examples=n, deadline=None, derandomize=True,
                    phases=(Phase.explicit, Phase.reuse, Phase.generate, Phase.target, Phase.shrink))


# ------------------------------------------------------------------------------------------------
# recording format

#: Characters of extra column names: CSV delimiters and quotes, non-ASCII letters, line breaks
#: (quoted by the writer, kept by the reader). Leading or trailing white space is refused by
#: save_recording (the reader strips header cells), so names are drawn without it at the ends.
NAME_CHARS = "abcxyzABXYZ019_-.()/[],\"'θδµ°\n\r\u2028\x85"


@st.composite
def finite_tables(draw):
    """``(columns, meta)`` of a valid recording: a uniform, jittered grid and finite values."""
    n = draw(st.integers(2, 60))
    step = draw(st.floats(1e-5, 1.0))
    t0 = draw(st.floats(-1e4, 1e4, **FINITE))
    jitter = draw(arrays(float, n, elements=st.floats(-0.01, 0.01)))
    columns = {"t": t0 + step * (np.arange(n) + jitter)}
    angle = st.floats(-0.4, 0.4)  # the reader refuses more than MAX_ANGLE = 0.5 rad
    columns["u"] = draw(arrays(float, n, elements=angle))
    columns["delta"] = draw(arrays(float, n, elements=angle))
    names = draw(st.lists(st.text(NAME_CHARS, min_size=1, max_size=8).filter(lambda x: x == x.strip()),
                          max_size=3, unique=True))
    for name in names:
        if name not in columns:
            columns[name] = draw(arrays(float, n, elements=st.floats(**FINITE)))
    order = draw(st.permutations(list(columns)))
    columns = {k: columns[k] for k in order}
    if draw(st.booleans()):
        number = st.floats(-1e3, 1e3, **FINITE)
        meta = {"kind": "closed", "kp": draw(number), "kd": draw(number), "mu": draw(number),
                "controller_rate": draw(st.none() | st.floats(1.0, 1e4))}
    else:
        meta = {"kind": "open"}
    if draw(st.booleans()):
        meta["sample_rate"] = 1.0 / float(np.median(np.diff(columns["t"])))
    if draw(st.booleans()):
        meta["description"] = draw(st.text(max_size=20))
    return columns, meta


def _bits(a):
    return np.ascontiguousarray(a, dtype=float).tobytes()


@_settings(150)
@given(finite_tables())
def test_any_finite_table_round_trips_exactly(table):
    columns, meta = table
    with tempfile.TemporaryDirectory() as tmp:
        path = save_recording(Path(tmp) / "rec.csv", columns, meta)
        rec = load_recording(path)
    assert list(rec.columns) == list(columns)
    for name, values in columns.items():
        assert _bits(rec.columns[name]) == _bits(values), name
    expected = {**meta, "units": dict(DEFAULT_UNITS)}
    expected.setdefault("sample_rate", 1.0 / float(np.median(np.diff(columns["t"]))))
    assert rec.meta == expected


NON_FINITE_SPELLINGS = ("nan", "NaN", "-nan", "inf", "-inf", "+inf", "Infinity", "-Infinity", "INF")


@_settings(150)
@given(finite_tables(), st.data())
def test_any_non_finite_table_is_refused_naming_column_and_row(table, data):
    columns, meta = table
    names = list(columns)
    n = columns["t"].size
    cells = data.draw(st.sets(st.tuples(st.sampled_from(names), st.integers(0, n - 1)),
                              min_size=1, max_size=6))
    spelled = {cell: data.draw(st.sampled_from(NON_FINITE_SPELLINGS)) for cell in cells}
    first_col = next(name for name in names if any(c == name for c, _ in cells))
    rows = sorted(r for c, r in cells if c == first_col)
    expected = (f"column '{first_col}' holds NaN or infinite values ({len(rows)} of them, first at "
                f"data row {rows[0] + 1})")
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bad.csv"
        with open(path, "w", newline="", encoding="utf-8") as fh:
            writer = csv.writer(fh)
            writer.writerow(names)
            for i in range(n):
                writer.writerow([spelled.get((name, i), repr(float(columns[name][i])))
                                 for name in names])
        sidecar_path(path).write_text(json.dumps(meta))
        try:
            load_recording(path)
        except RecordingError as exc:
            assert str(exc) == f"{path}: {expected}"
        else:
            raise AssertionError("load_recording accepted non-finite values")

        values = {name: columns[name].copy() for name in names}
        for (name, i), word in spelled.items():
            values[name][i] = float(word)
        target = Path(tmp) / "sub" / "refused.csv"
        try:
            save_recording(target, values, meta)
        except RecordingError as exc:
            assert str(exc) == f"{target}: {expected}"
        else:
            raise AssertionError("save_recording wrote non-finite values")
        assert not target.exists() and not sidecar_path(target).exists()


# ------------------------------------------------------------------------------------------------
# simulator


class DrawnGenerator:
    """Stands in for the ``numpy.random.Generator`` of :mod:`tvcid.studies.benchmarks.scenarios`.

    Every draw the generator asks for (``uniform(low, high)``, ``integers``, ``choice``,
    ``permutation``) is made by ``hypothesis`` within the same bounds, so the scenario code keeps
    its ranges and ``hypothesis`` explores them (ends included) and shrinks failures. A method the
    generator starts using and this class lacks fails the test loudly (AttributeError).
    """

    def __init__(self, data):
        self.data = data

    def uniform(self, low=0.0, high=1.0):
        return self.data.draw(st.floats(float(low), float(high)))

    def integers(self, low, high=None):
        if high is None:
            low, high = 0, low
        return self.data.draw(st.integers(int(low), int(high) - 1))

    def choice(self, options):
        return self.data.draw(st.sampled_from(list(options)))

    def permutation(self, n):
        return np.array(self.data.draw(st.permutations(range(int(n)))))


def _experiments(design, data):
    """The design's experiments: each closed-loop setting with its controller continuous and held
    at 200 Hz, each open-loop square or sine and a step of its amplitude."""
    out = []
    for rd in design:
        if rd.kind == "closed":  # the design holds the controller at 200 Hz or not: run both
            out += [ClosedLoop(rd.kp, rd.kd, rd.mu, sample_rate=rate) for rate in (None, 200.0)]
        else:
            out.append(rd.experiment())
            event(f"open loop {rd.waveform}")
            start = data.draw(st.floats(0.0, 0.5), label="step start")
            out.append(OpenLoop.step(rd.amplitude, start=start))
            event("open loop step")
    return out


def _step_for(rate):
    """The longest step up to the default that the acquisition rate divides (2 kHz: 1/6000 s)."""
    return 1.0 / (rate * math.ceil(1.0 / (rate * DEFAULT_DT) - 1e-9))


def _check_run(params, experiment, t_end, rate):
    """Simulate; a returned trajectory must be finite and consistent. ``(diverged, trajectory)``."""
    try:
        tr = simulate(params, experiment, t_end, dt=_step_for(rate), rate=rate)
    except SimulationDiverged as exc:
        assert "diverged" in str(exc)
        event("diverged")
        return True, None
    event("finite")
    for name, values in tr.signals().items():
        assert np.all(np.isfinite(values)), f"{name} holds NaN or inf"
    n_steps = int(round(t_end / tr.dt))
    decimation = int(round(1.0 / (rate * tr.dt)))
    assert tr.t.size == n_steps // decimation + 1
    np.testing.assert_allclose(np.diff(tr.t), 1.0 / rate, rtol=1e-9)
    assert tr.t[0] == 0.0
    assert np.all(np.abs(tr.x) <= DEFAULT_BOUND) and np.all(np.abs(tr.theta) <= DEFAULT_BOUND)
    r = params.backlash
    assert np.all(tr.backlash >= tr.x - r) and np.all(tr.backlash <= tr.x + r)
    if isinstance(experiment, OpenLoop):
        assert np.array_equal(tr.u, experiment.command(tr.t))
        assert np.all(tr.theta == 0.0)
    return False, tr


def _check_batch(params, experiments, t_end, rate, singles):
    """The batch runs diverge where the single ones do and otherwise record the same signals
    (``u`` is the command in both, never the solver's averages of a square command's edges)."""
    batch = simulate_batch([params] * len(experiments), experiments, t_end, dt=_step_for(rate),
                           rate=rate)
    for i, (diverged, tr) in enumerate(singles):
        assert batch.diverged[i] == diverged, (i, batch.status[i])
        if not diverged:
            for name, values in tr.signals().items():
                np.testing.assert_allclose(batch.signal(name)[i], values, rtol=1e-9, atol=1e-15,
                                           err_msg=name)


@_settings(100)
@given(st.data())
def test_simulator_returns_finite_trajectory_or_reports_divergence(data):
    rng = DrawnGenerator(data)
    truth = draw_truth(rng)  # any kept structure, the generator's ranges
    design, _ = draw_design(rng)
    t_end = data.draw(st.floats(1.0, 3.0), label="t_end")
    rate = design[0].rate
    experiments = _experiments(design, data)
    singles = [_check_run(truth, exp, t_end, rate) for exp in experiments]
    _check_batch(truth, experiments, t_end, rate, singles)


@_settings(100)
@given(st.sampled_from(sorted(HYPOTHESES)), st.data())
def test_paper_hypotheses_with_drawn_parameters_never_crash(name, data):
    base = make_hypothesis(name)
    structure = Structure.of_params(base)
    truth = draw_truth(DrawnGenerator(data), structure)
    basin = BasinConfig()
    overrides = {k: getattr(truth, k) for k in structure.parameter_names()}
    overrides.update(
        y0=data.draw(st.floats(-basin.y_range, basin.y_range), label="y0"),
        yd0=data.draw(st.floats(-basin.yd_range, basin.yd_range), label="yd0"),
        x0=data.draw(st.floats(-basin.x_range, basin.x_range), label="x0"),
    )
    params = make_hypothesis(name, **overrides)
    assert type(params) is type(base) and Structure.of_params(params) == structure
    design, _ = draw_design(DrawnGenerator(data))
    t_end = data.draw(st.floats(1.0, 3.0), label="t_end")
    for exp in _experiments(design, data):
        _check_run(params, exp, t_end, design[0].rate)


# ------------------------------------------------------------------------------------------------
# limit-cycle features of a pure sinusoid


@_settings(500)
@given(
    amplitude=st.floats(1e-4, 0.1),
    frequency=st.floats(0.5, 20.0),
    fs=st.floats(200.0, 1000.0),
    periods=st.floats(3.5, 12.0),
    phase=st.floats(0.0, 2 * math.pi),
    offset=st.floats(-0.05, 0.05),
    t0=st.floats(0.0, 1e3),
)
def test_features_of_a_pure_sinusoid(amplitude, frequency, fs, periods, phase, offset, t0):
    n = int(periods * fs / frequency) + 1
    t = t0 + np.arange(n) / fs
    x = offset + amplitude * np.sin(2 * np.pi * frequency * (t - t0) + phase)
    f = limit_cycle_features(t, x)

    assert math.floor(periods) - 2 <= f.n_periods <= math.floor(periods)
    used = f.n_periods * fs / frequency  # samples in the whole periods
    cos = math.cos(math.pi * frequency / fs)
    assert amplitude * cos * (1 - 1e-9) <= f.amplitude <= amplitude * (1 + 1e-9)
    assert abs(f.amplitude_drift) <= (1 - cos) / cos + 1e-9
    assert abs(f.frequency_hz / frequency - 1) <= 0.05 / used
    assert f.period_jitter < 5e-3
    assert abs(f.mean - offset) <= amplitude / used
    assert abs(f.harmonics[0] / amplitude - 1) <= 2 / used
    below_nyquist = [k for k in range(2, len(f.harmonics) + 1) if k * frequency < fs / 2]
    for k in below_nyquist:
        assert f.harmonics[k - 1] <= amplitude / used, k


# ------------------------------------------------------------------------------------------------
# nonlinearities

values = st.floats(-1e3, 1e3, **FINITE)
signals = arrays(float, st.integers(1, 40), elements=values)
widths = st.floats(0.0, 10.0)
scales = st.floats(1e-3, 1e3)


def _close(a, b, scale):
    """Equal within 1e-12 of ``scale`` (and within the subnormal range, 1e-300)."""
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-12 * scale + 1e-300)


@_settings(300)
@given(signals, widths)
def test_dead_zone_definition(q, z):
    out = dead_zone(q, z)
    assert np.array_equal(dead_zone(-q, z), -out)  # odd
    inside = np.abs(q) <= z
    assert np.all(out[inside] == 0.0)
    assert np.all(np.sign(out[~inside]) == np.sign(q[~inside]))
    _close(np.abs(out[~inside]), np.abs(q[~inside]) - z, np.max(np.abs(q)) + z)
    assert np.all(np.abs(out) <= np.abs(q))
    order = np.argsort(q, kind="stable")
    assert np.all(np.diff(out[order]) >= 0)  # nondecreasing
    # slope 1 beyond the band on each side, 1-Lipschitz everywhere
    scale = np.max(np.abs(q)) + z
    for side in (q > z, q < -z):
        d_out = out[side][:, None] - out[side][None, :]
        d_q = q[side][:, None] - q[side][None, :]
        _close(d_out, d_q, scale)
    gap = np.abs(out[:, None] - out[None, :]) - np.abs(q[:, None] - q[None, :])
    assert np.all(gap <= 1e-12 * scale)
    _close(out + saturation(q, z), q, scale)  # DZ_z + sat_z = identity
    assert np.array_equal(dead_zone(q, 0.0), q)
    assert np.array_equal(np.array([kernel_dead_zone(float(v), float(z)) for v in q]), out)


@_settings(300)
@given(signals, widths, widths, scales)
def test_dead_zone_homogeneity_and_composition(q, z1, z2, c):
    scale = np.max(np.abs(q)) + z1 + z2
    _close(dead_zone(c * q, c * z1), c * dead_zone(q, z1), c * scale)
    _close(dead_zone(dead_zone(q, z2), z1), dead_zone(q, z1 + z2), scale)


@_settings(300)
@given(signals, widths, values)
def test_play_operator_definition(x, r, b0):
    out = play_operator(x, r, b0)
    assert out.shape == x.shape
    assert np.array_equal(play_operator(-x, r, -b0), -out)  # odd
    assert np.all(out >= x - r) and np.all(out <= x + r)  # within r of the input, every sample
    memory, stepped = b0, []
    for v in x:
        memory = play_step(memory, v, r)
        stepped.append(memory)
    assert np.array_equal(np.array(stepped), out)
    assert np.array_equal(play_operator(x, 0.0, b0), x)


@_settings(300)
@given(signals, widths, values, values)
def test_play_operator_forgets_its_memory_once_the_input_moved_by_2r(x, r, b0, b1):
    a, b = play_operator(x, r, b0), play_operator(x, r, b1)
    lo, hi = x - r, x + r
    # an earlier sample's lower (upper) clamp above (below) this sample's upper (lower) clamp
    moved = (np.maximum.accumulate(lo) >= hi) | (np.minimum.accumulate(hi) <= lo)
    moved = np.maximum.accumulate(moved)  # once forgotten, forgotten for good
    assert np.array_equal(a[moved], b[moved])
    event(f"moved by 2r at {'some' if moved.any() else 'no'} sample")


@_settings(300)
@given(signals, widths, values, st.integers(1, 4), st.data())
def test_play_operator_is_rate_independent(x, r, b0, repeat, data):
    out = play_operator(x, r, b0)
    assert np.array_equal(play_operator(np.repeat(x, repeat), r, b0), np.repeat(out, repeat))
    # insert points on the segment between consecutive samples: same output at the old samples
    fractions = data.draw(arrays(float, max(x.size - 1, 0), elements=st.floats(0.0, 1.0)))
    mids = np.clip(x[:-1] + fractions * (x[1:] - x[:-1]),
                   np.minimum(x[:-1], x[1:]), np.maximum(x[:-1], x[1:]))
    refined = np.empty(2 * x.size - 1)
    refined[0::2], refined[1::2] = x, mids
    assert np.array_equal(play_operator(refined, r, b0)[0::2], out)


@_settings(300)
@given(signals, widths, widths, values, st.floats(-1.0, 1.0), scales)
def test_play_operator_homogeneity_and_composition(x, r1, r2, b1, where, c):
    scale = np.max(np.abs(x)) + r1 + r2 + abs(b1)
    _close(play_operator(c * x, c * r1, c * b1), c * play_operator(x, r1, b1), c * scale)
    b2 = b1 + where * r2  # |b2 - b1| <= r2
    _close(play_operator(play_operator(x, r1, b1), r2, b2), play_operator(x, r1 + r2, b2), scale)
