"""A square wave known only as samples, replayed with the edge timing its samples allow (issue 12
item 3: "the replay error itself becomes a mismatch").

Case (from the coverage benchmark's draw 3, seed 2003): a square of 0.313 Hz sampled at 1 kHz from
t = 0, so every edge falls 1596 samples after the previous one while the true half period is
1595.81 samples; the hold replay drifts to 0.9 ms late by the fifth edge. The truth's open-loop
residuals were 3x the sensor noise, and the calibration's intervals excluded it.
"""
import json

import numpy as np
import pytest

from discovery.calibration import synthetic_recording
from discovery.calibration.likelihood import make_term
from models import M002, OpenLoop
from models.commands import command_from_samples, edge_alternatives
from models.recording import load_recording

FREQUENCY = 0.31331990500313334
NOISE = 2.5e-5


def test_alternatives_span_the_true_edges():
    t = np.arange(0, 9.0, 1e-3)
    exact = OpenLoop.square(0.02, FREQUENCY)
    u = exact.command(t)
    true_edges = np.arange(1, 6) / (2 * FREQUENCY)
    hold = command_from_samples(t, u).t_samples
    assert np.max(np.abs(hold - true_edges)) > 8e-4  # the hold replay drifts by ~a sample
    alternatives = edge_alternatives(t, u)
    assert len(alternatives) > 10
    errors = [np.max(np.abs(a.t_samples - true_edges)) for a in alternatives]
    assert min(errors) < 1.5e-4
    for a in alternatives:  # every alternative reproduces the samples
        assert np.array_equal(a.command(t), u)


def test_not_regular_commands_have_no_alternatives():
    t = np.arange(0, 4.0, 1e-3)
    assert edge_alternatives(t, 0.01 * np.sin(2 * np.pi * t)) == []
    assert edge_alternatives(t, np.where(t > 1.0, 0.01, 0.0)) == []  # one edge: a step


def _square_as_samples(path, seed):
    """M002 driven by the square, recorded measured-style: the command only as samples."""
    synthetic_recording(M002(), OpenLoop.square(0.01, FREQUENCY), 9.0, NOISE, seed, path, dt=2e-4)
    sidecar = path.with_suffix(".json")
    meta = json.loads(sidecar.read_text())
    for key in ("waveform", "amplitude", "frequency", "start", "offset", "from_rest",
                "hypothesis", "parameters"):
        meta.pop(key, None)
    sidecar.write_text(json.dumps(meta))
    return load_recording(path)


def test_replay_at_the_centre_with_a_shared_timing_uncertainty(tmp_path):
    """The replay at the centre of the allowed timings, its spread a rank-2 covariance (phase
    and half period): the truth's residuals less the most probable replay component are the
    sensor's noise, and a delay shifted within the timing's ambiguity (the allowed mean edge
    time has an sd of 0.155 ms) is not excluded by thousands of samples counting the timing again
    and again."""
    truth = M002()
    rec = _square_as_samples(tmp_path / "square.csv", 3)
    term = make_term(rec, "waveform", 10.0, 6.0, 5e-4)
    term.setup(truth)
    before = float(np.sqrt(np.mean(term.residuals([truth])[0] ** 2)))
    assert term.choose_command(truth)
    assert before > 1.5 * NOISE  # 1.84x: the replay error dominates the noise
    assert term.replay_basis is not None and 1 <= term.replay_basis.shape[1] <= 4
    sigma = np.array([NOISE])
    scaled = term.scaled_residuals(term.residuals([truth])[0], NOISE)
    assert float(np.sqrt(np.mean(scaled**2))) == pytest.approx(NOISE, rel=0.15)
    # 0.1 ms more delay costs 5.3 nats with the shared covariance (mostly the response to the
    # step at the record's start, whose time is known), 57 with the spread as independent
    # per-sample variance
    shifted = truth.replace(delay=truth.delay + 1e-4)
    drop = float(term.loglike([truth], sigma)[0] - term.loglike([shifted], sigma)[0])
    diagonal = float(term.loglike([truth], sigma, pointwise=True).sum()
                     - term.loglike([shifted], sigma, pointwise=True).sum())
    assert drop < 0.25 * diagonal
    edges = term.command_edges()
    basis = term.replay_basis
    term2 = make_term(rec, "waveform", 10.0, 6.0, 5e-4)
    term2.setup(truth)
    term2.set_command_edges(edges)  # what a resumed chain does
    term2.replay_basis = basis
    assert np.array_equal(term2.loglike([truth], sigma), term.loglike([truth], sigma))


def test_low_rank_loglike_equals_the_dense_gaussian():
    """The Woodbury evaluation against the dense multivariate normal."""
    from scipy.stats import multivariate_normal

    from discovery.calibration.likelihood import _WaveformSolverError

    rng = np.random.default_rng(5)
    n = 200
    term = _WaveformSolverError()
    term.solver_var = rng.uniform(0, 1e-9, n)
    term.replay_basis = rng.standard_normal((n, 2)) * 2e-5
    term.inflation = 1.7
    sigma = 3e-5
    res = rng.standard_normal((2, n)) * 4e-5
    cov = term.inflation * (np.diag(sigma**2 + term.solver_var)
                            + term.replay_basis @ term.replay_basis.T)
    exact = [multivariate_normal(np.zeros(n), cov).logpdf(r) for r in res]
    got = term._gaussian_loglike(res, np.array([sigma, sigma]), pointwise=False)
    assert np.allclose(got, exact, rtol=0, atol=1e-8)


def test_replay_variance_marks_the_edges(tmp_path):
    """The response's spread over the allowed timings is large at the edges, nil between them."""
    term = make_term(_square_as_samples(tmp_path / "sq.csv", 4), "waveform", 10.0, 6.0, 5e-4)
    term.setup(M002())
    term.choose_command(M002())
    sd = np.sqrt(term.replay_var)  # the diagonal of the low-rank covariance
    edge = 1 / (2 * FREQUENCY)
    near = np.abs(term.tau - edge - 0.01) < 0.01
    far = np.abs(term.tau - edge - 0.8) < 0.1
    assert sd[near].max() > 3 * NOISE
    assert sd[far].max() < 0.1 * NOISE
