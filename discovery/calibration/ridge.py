"""Non-uniqueness of a limit-cycle fit: the dead-zone/backlash ridge and how more data shrink it.

A single limit cycle fixes an amplitude and a frequency; paper 002's describing-function (DF)
analysis turns these two numbers into a one-parameter family of (backlash f, dead zone zm) pairs.
:class:`RidgeAnalysis` compares posteriors of the same parameters under different data (one cycle's
amplitude and frequency, its waveform, a second controller setting, open-loop tests): correlation
of ``ln f`` and ``ln zm``, marginal 90 % widths, the whole correlation matrix, and a plot of the
samples over the DF family.

The DF family comes from :func:`tvcid.discovery.describing.paper002_family` (paper 002 eqs. 13-18 with
the corrections of docs/models.md#errata) for the recorded amplitude and frequency, the controller and the
hypothesis' structure; where that does not apply (another structure, no controller given) from
the tabulated corrected family of docs/models.md#errata at controller A (computed for the HWIL cycle 4.89e-3 rad
at 8.57 rad/s, Td = 7 ms), scaled to the recorded amplitude by the homogeneity of both DFs. The
iso-frequency line ``f/zm = const`` (docs/models.md#what-a-recording-pins: frequency and
shape depend only on the ratio) is drawn through the posterior median. The DF method is an
approximation here (it predicts 8.88 rad/s where the simulation gives 8.60): the family shows the
direction of the trade-off, not its exact place.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["RidgeAnalysis", "df_family", "PAPER002_FAMILY_A"]

#: docs/models.md#errata: paper 002's family at controller A with the three
#: algebra slips corrected (K1 = 4.89e-3 rad, w = 8.57 rad/s, Td = 7 ms, f as the play half width):
#: (f, zm) pairs in rad.
PAPER002_FAMILY_A = {
    "amplitude": 4.89e-3,
    "frequency": 8.57,
    "backlash": (1e-4, 2e-4, 3e-4, 4e-4, 4.364e-4, 5e-4, 7e-4, 1e-3),
    "dead_zone": (1.011e-3, 1.111e-3, 1.208e-3, 1.301e-3, 1.333e-3, 1.389e-3, 1.554e-3, 1.769e-3),
}


def df_family(amplitude, frequency=None, controller=None, params=None, backlash=None):
    """(backlash, dead_zone) arrays of paper 002's DF family for a cycle of ``amplitude`` (rad).

    Uses :func:`tvcid.discovery.describing.paper002_family` (variant "corrected") when ``frequency``,
    ``controller`` and ``params`` are given and the structure is paper 002's; otherwise the tabulated family of docs/models.md#errata,
    scaled by homogeneity. Returns ``(f, zm, source)``.
    """
    if frequency is not None and controller is not None and params is not None:
        try:
            from tvcid.discovery.describing import paper002_family

            grid = np.geomspace(5e-5, 1e-3, 40) if backlash is None else np.asarray(backlash, float)
            fam = paper002_family(amplitude, frequency, controller, params,
                                  backlash_half_widths=grid, variant="corrected")
            ok = np.isfinite(fam.dead_zone)
            if ok.sum() >= 2:
                return (fam.backlash_half_width[ok], fam.dead_zone[ok],
                        f"tvcid.discovery.describing.paper002_family (corrected), {amplitude:.4g} rad at "
                        f"{frequency:.4g} rad/s, Td {fam.delay:g} s")
        except (ImportError, ValueError, TypeError):
            pass  # another structure or no describing package: the tabulated family
    k = float(amplitude) / PAPER002_FAMILY_A["amplitude"]
    f = k * np.asarray(PAPER002_FAMILY_A["backlash"])
    zm = k * np.asarray(PAPER002_FAMILY_A["dead_zone"])
    return f, zm, ("docs/models.md#errata paper 002 family at controller A (corrected algebra), scaled by "
                   f"homogeneity to amplitude {amplitude:.4g} rad")


@dataclass(eq=False)
class RidgeAnalysis:
    """Posteriors of the same two parameters under different data sets.

    Parameters
    ----------
    posteriors : dict label -> Posterior
        In the order of increasing data (e.g. "A: amplitude+frequency", "A+B", "A+B+open").
    pair : tuple of str
        The two parameters of the ridge (default backlash, dead_zone).
    amplitude : float or None
        The recorded cycle amplitude ``(max - min)/2`` (rad; :func:`tvcid.models.cycle_reading.robust_amplitude` for noisy
        data) that places the DF family; ``None`` draws no family.
    truths : dict or None
    frequency : float or None
        Recorded cycle frequency (rad/s), with ``controller`` and ``params`` for
        :func:`tvcid.discovery.describing.paper002_family`.
    controller : tvcid.models.ClosedLoop or None
    params : tvcid.models.ActuatorParams or None
        The hypothesis (its structure; the widths are ignored).
    """

    posteriors: dict
    pair: tuple = ("backlash", "dead_zone")
    amplitude: float | None = None
    truths: dict | None = None
    frequency: float | None = None
    controller: object = None
    params: object = None
    rows: list = field(init=False)

    def __post_init__(self):
        a, b = self.pair
        self.rows = []
        for label, post in self.posteriors.items():
            ia, ib = post.names.index(a), post.names.index(b)
            la = np.log(post.samples[:, ia])
            lb = np.log(post.samples[:, ib])
            widths, inside = {}, {}
            for n in post.names:
                lo, hi = post.interval(n, 0.90)
                med = float(np.median(post.samples[:, post.names.index(n)]))
                widths[n] = (hi - lo) / abs(med) if med else float("nan")
                if self.truths and n in self.truths:
                    inside[n] = bool(lo <= self.truths[n] <= hi)
            self.rows.append({
                "label": label,
                "corr_log_pair": float(np.corrcoef(la, lb)[0, 1]),
                "width90_relative": widths,
                "truth_inside_90": inside,
                "correlation": post.summary()["correlation"],
                "converged": bool(post.report.converged),
                "n_over_tau": float(post.report.n_over_tau),
                "tau_max": float(max(post.report.tau)),
            })

    def table(self) -> list:
        return self.rows

    def shrinkage(self):
        """Marginal 90 % widths of each later data set relative to the first, per parameter."""
        first = self.rows[0]["width90_relative"]
        out = {}
        for r in self.rows[1:]:
            out[r["label"]] = {n: r["width90_relative"][n] / first[n]
                               for n in r["width90_relative"] if n in first and first[n]}
        return out

    def to_dict(self):
        return {"pair": list(self.pair), "rows": self.rows, "shrinkage": self.shrinkage()}

    def plot(self, ax=None, max_points=3000, seed=0, zoom=None):
        """Samples in (f, zm), log-log, per data set, over the DF family and the iso-frequency line.

        ``zoom`` (e.g. 0.05) limits the axes to that relative distance around the truth (or the
        last posterior's median), where the narrow posteriors of the richer data sets show.
        """
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(6, 5))
        a, b = self.pair
        rng = np.random.default_rng(seed)
        med = None
        for k, (label, post) in enumerate(self.posteriors.items()):
            s = post.samples
            if s.shape[0] > max_points:
                s = s[rng.choice(s.shape[0], max_points, replace=False)]
            x, y = s[:, post.names.index(a)], s[:, post.names.index(b)]
            row = self.rows[k]
            ax.plot(x, y, ".", ms=1.5 + 0.5 * k, alpha=0.35, color=f"C{k}",
                    label=f"{label} (corr ln {row['corr_log_pair']:.2f})")
            if med is None:
                med = (float(np.median(x)), float(np.median(y)))
        if self.amplitude is not None:
            f, zm, source = df_family(self.amplitude, self.frequency, self.controller, self.params)
            ax.plot(f, zm, "k--", lw=1.2, label="DF family (paper 002)")
            ax.text(0.02, 0.02, source, transform=ax.transAxes, fontsize=5)
        if med is not None:
            fx = np.geomspace(ax.get_xlim()[0], ax.get_xlim()[1], 20)
            ax.plot(fx, med[1] / med[0] * fx, ":", color="gray", lw=1,
                    label="iso-frequency f/zm = const")
        if self.truths and self.truths.get(a) is not None:
            ax.plot(self.truths[a], self.truths[b], "r*", ms=12, label="truth")
        if zoom is not None:
            if self.truths and self.truths.get(a) is not None:
                ca, cb = self.truths[a], self.truths[b]
            else:
                last = list(self.posteriors.values())[-1]
                ca = float(np.median(last.samples[:, last.names.index(a)]))
                cb = float(np.median(last.samples[:, last.names.index(b)]))
            ax.set_xlim(ca * (1 - zoom), ca * (1 + zoom))
            ax.set_ylim(cb * (1 - zoom / 4), cb * (1 + zoom / 4))
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"{a} (rad)")
        ax.set_ylabel(f"{b} (rad)")
        ax.legend(fontsize=6)
        return ax
