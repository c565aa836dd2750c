"""The figures and the report lines of ``h6_controller_design``.

``filters.png`` (lead and notch sweeps), ``boundary.png`` (the stability boundary along Kd at
controller A's Kp), ``map.png`` (the Kp x Kd map) and ``design.png`` (the ranked menu), all from
the study's summary and maps; :func:`report_lines` writes the summary's numbers as Markdown.
"""
from __future__ import annotations

import numpy as np

from tvcid.figures import pyplot

from .h6_checks import SETTING_A


def _generating_markers(ax, x, rows, name, scale):
    """The generating model's cycles (long runs) as crosses; its divergences as red bars."""
    xs = [v for v, g in zip(x, rows) if g[name] is not None]
    ys = [g[name] * scale for g in rows if g[name] is not None]
    ax.plot(xs, ys, "kx", ms=7, label="generating model (long run)")
    for v, g in zip(x, rows):
        if g["outcome"] == "diverged":
            ax.axvline(v, color="r", lw=3, alpha=0.3)


def _log_ticks(ax, ticks):
    from matplotlib.ticker import NullFormatter

    ax.set_xscale("log")
    ax.set_xticks(ticks)
    ax.set_xticklabels([f"{t:g}" for t in ticks])
    ax.xaxis.set_minor_formatter(NullFormatter())


def plot_filters(summary, path, lead_map, notch_map):
    """Lead and notch sweeps (band, median, DF, generating model) beside the plain PD's band."""
    plt = pyplot()
    fig, axes = plt.subplots(2, 2, figsize=(12, 8.5), constrained_layout=True)
    plain = summary["plain_pd"]
    lead_map.plot(axes=axes[0])
    notch_map.plot(axes=axes[1])
    sweeps = ((axes[0], lead_map.values[0], summary["lead"]["sweep_generating"],
               f"lead (1 + s/{summary['lead']['zero']:g})/(1 + s/p) at controller A",
               "lead pole p (rad/s)", (6, 10, 20, 40, 60)),
              (axes[1], notch_map.values[0], summary["notch"]["sweep_generating"],
               "bending {frequency:g} rad/s, damping {damping:g}, gain {gain:g} + notch at its "
               "frequency".format(**summary["notch"]["bending"]),
               "notch damping (its width)", (0.02, 0.05, 0.1, 0.2, 0.5)))
    for row, x, gen, title, xlabel, ticks in sweeps:
        for ax, name, scale in ((row[0], "amplitude", 1e3), (row[1], "frequency", 1.0)):
            q = plain[name]
            if q["q50"] is not None:
                ax.axhspan(q["q05"] * scale, q["q95"] * scale, color="0.6", alpha=0.4)
                ax.axhline(q["q50"] * scale, color="0.3", lw=1, ls=":",
                           label="plain PD (no filter, no bending)")
            _generating_markers(ax, x, gen, name, scale)
            _log_ticks(ax, [t for t in ticks if x[0] <= t <= x[-1]])
            ax.set_xlabel(xlabel)
            ax.set_title(title, fontsize=9)
            ax.legend(fontsize=7)
    from matplotlib.ticker import ScalarFormatter

    axes[1][0].set_yscale("log")
    axes[1][0].yaxis.set_major_formatter(ScalarFormatter())
    axes[1][0].yaxis.set_minor_formatter(ScalarFormatter())
    for row, sweep in ((axes[0], summary["lead"]), (axes[1], summary["notch"])):
        # the map's line plot marks divergence at 0 rad/s; keep the cycles' range in view
        f = [v for v in sweep["sweep"]["frequency_q50"] + sweep["sweep"]["df_frequency"]
             if v is not None]
        f += [g["frequency"] for g in sweep["sweep_generating"] if g["frequency"] is not None]
        f.append(plain["frequency"]["q50"] or f[0])
        row[1].set_ylim(0.97 * min(f), 1.03 * max(f))
    bent = summary["notch"]["pd_with_bending"]
    axes[1][0].text(0.02, 0.97, "PD with the bending mode, no notch: "
                    f"{100 * bent['fraction_diverging']:.0f} % of draws diverge "
                    f"(generating model: {bent['generating']['outcome']})",
                    transform=axes[1][0].transAxes, fontsize=8, va="top")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_boundary(summary, path):
    """Fraction of draws diverging and the cycle's amplitude along Kd at controller A's Kp."""
    plt = pyplot()
    b = summary["boundary_at_A"]
    kd = np.array(b["kd"])
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4), constrained_layout=True)
    ax1.plot(kd, b["fraction_diverging"], "o-", ms=4, label="posterior draws")
    ax1.plot(kd, [1.0 if g["outcome"] == "diverged" else 0.0 for g in b["generating"]], "kx",
             ms=7, label="generating model (long run)")
    ax1.set_ylabel("fraction diverging")
    amp = np.array([np.nan if v is None else v for v in b["amplitude_q50"]], dtype=float)
    ax2.semilogy(kd, 1e3 * amp, "o-", ms=4, label="median over the draws")
    ax2.semilogy(kd, [np.nan if g["amplitude"] is None else 1e3 * g["amplitude"]
                      for g in b["generating"]], "kx", ms=7, label="generating model (long run)")
    ax2.set_ylabel("amplitude of delta (mrad)")
    for ax in (ax1, ax2):
        ax.axvline(SETTING_A.kd, color="0.5", ls=":", label="controller A")
        ax.set_xlabel(f"Kd (s), Kp {b['kp']}, mu {SETTING_A.mu}")
        ax.legend(fontsize=8)
    fig.suptitle("stability boundary at controller A's gain")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_map(cmap, disagreements, draws, path):
    """The Kp x Kd map (:meth:`tvcid.discovery.prediction.CycleMap.plot`) with controller A starred and
    the settings where the draws' majority outcome differs from the generating model's crossed."""
    plt = pyplot()
    axes = cmap.plot()
    fig = axes[0].figure
    for ax in axes:
        ax.plot([SETTING_A.kd], [SETTING_A.kp], "w*", ms=12, mec="k")
        for cell in disagreements:
            ax.plot(cell["kd"], cell["kp"], "x", color="c", ms=9, mew=2)
    fig.suptitle(f"M000 calibrated on the bundled records: {draws} draws, mu {SETTING_A.mu}"
                 "\nstar: controller A; black line: half the draws diverge; cyan x: the draws' "
                 "majority outcome differs from the generating model's", fontsize=10)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_design(ranking, path):
    """The experiment menu ranked (:meth:`tvcid.discovery.prediction.design.DesignRanking.plot`)."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 0.55 * len(ranking.rows) + 1.8), constrained_layout=True)
    ranking.plot(ax)
    ax.set_title("expected 90 % width after / before each test (best first)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_corner(cal, path):
    """The calibration's posterior corner plot."""
    plt = pyplot()
    fig = cal.posterior_.plot_corner()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _fmt_q(q, scale=1.0, digits=4):
    if q["q50"] is None:
        return "none oscillates"
    return (f"{q['q50'] * scale:.{digits}g} [{q['q05'] * scale:.{digits}g}, "
            f"{q['q95'] * scale:.{digits}g}]")


def _df(d):
    df = d["describing_function"]
    if not df or df.get("amplitude") is None:
        return (df or {}).get("note", "—")
    return f"{df['amplitude'] * 1e3:.3g} mrad (first harmonic) at {df['frequency']:.3g} rad/s"


def _gen(d):
    g, w = d["generating"], d.get("generating_wander")
    if g["amplitude"] is None:
        return g["outcome"]
    out = f"{g['amplitude'] * 1e3:.4g} mrad at {g['frequency']:.4g} rad/s"
    if w:
        a, f = w["amplitude"], w["frequency"]
        out += (f" (its {w['window']:g} s windows: {a['min'] * 1e3:.4g}-{a['max'] * 1e3:.4g} mrad, "
                f"{f['min']:.4g}-{f['max']:.4g} rad/s; "
                f"{100 * w['fraction_windows_over_settled_drift']:.0f} % of them would read as "
                "not settled)")
    return out


def report_lines(summary) -> list:
    """Markdown of the study's numbers for ``results/report.md`` (figures are embedded there).

    Parameters
    ----------
    summary : dict
        What :func:`run` returned (or ``summary.json``).

    Returns
    -------
    list of str
        Lines: the fit's table, the map's counts, band widths and boundary, the examples at
        controller A beside the describing function and the generating model, the ranking.
    """
    fit, m = summary["fit"], summary["map"]
    lines = [f"Fit: M000 on {', '.join(fit['recordings'])}, {fit['iterations']} steps x "
             f"{fit['walkers']} walkers (converged: {fit['converged']}, N/tau "
             f"{fit['n_over_tau']:.1f}), in-loop noise power fixed at "
             f"{fit['noise_power_fixed']:.3g} "
             "rad^2/Hz (floor of the square record).", "",
             "| parameter | median | 90 % interval | width % | truth | inside |",
             "|---|---|---|---|---|---|"]
    for n, p in fit["parameters"].items():
        lines.append(f"| {n} | {p['q50']:.5g} | [{p['q05']:.5g}, {p['q95']:.5g}] | "
                     f"{p['width90_pct']:.2f} | "
                     f"{p['truth'] if p['truth'] is not None else '—'} | "
                     f"{p['truth_inside_90'] if p['truth_inside_90'] is not None else '—'} |")
    bw = m["band_widths"]
    crit = summary["boundary_at_A"]["critical_kd"]
    lines += ["", f"Map ({m['shape'][0]} Kp x {m['shape'][1]} Kd, {summary['draws']} draws, "
              f"mu {m['mu']}): {m['cells_oscillating']} settings oscillate, "
              f"{m['cells_diverging']} diverge, {m['cells_at_rest']} rest; {m['cells_split']} "
              "settings split the draws (5-95 % diverging)"
              + (f"; at {m['cells_not_settled']} most draws have not settled on a cycle (amplitude "
                 "still drifting across the window)" if m.get("cells_not_settled") else "")
              + ". 90 % band width where the loop "
              f"oscillates: amplitude median {bw['amplitude']['median_pct']:.2g} %, max "
              f"{bw['amplitude']['max_pct']:.2g} %; frequency median "
              f"{bw['frequency']['median_pct']:.2g} %, max {bw['frequency']['max_pct']:.2g} %. "
              "DF of the median model vs the median simulated frequency: median "
              f"{bw['df_frequency_error']['median_pct']:.2g} %, max "
              f"{bw['df_frequency_error']['max_pct']:.2g} %.", "",
              f"Against the generating model's {summary['config']['truth_seconds']:g} s runs at "
              f"every setting: the draws' majority outcome agrees at "
              f"{100 * m['generating_check']['agreement']:.1f} % of them"
              + "".join(f"; not at Kp {c['kp']:.3g}, Kd {c['kd']:.3g} ("
                        f"{100 * c['fraction_diverging']:.0f} % of draws diverge, the generating "
                        f"model: {c['generating_outcome']})"
                        for c in m["generating_check"]["disagreements"])
              + "; where both oscillate the median amplitude is off by "
              f"{m['generating_check']['amplitude_error_pct']['median']:.2g} % (median), "
              f"{m['generating_check']['amplitude_error_pct']['max']:.2g} % (max).", "",
              "Stability boundary (Kd interval where the majority of draws stops diverging): "
              + "; ".join(f"Kp {r['kp']:.3g}: " + (", ".join(f"{a:.3g}-{b:.3g}"
                                                            for a, b in r['kd_intervals'])
                                                  or "none in the grid")
                          for r in m["boundary"]) + ".", "",
              f"At controller A's Kp {summary['boundary_at_A']['kp']}: the draws diverge below a "
              "critical Kd between "
              + (f"{crit['grid_interval'][0]:.4g} and {crit['grid_interval'][1]:.4g}"
                 if crit["grid_interval"] is not None else "— (not found in the scan)")
              + f" ({crit['draws_split']} scan points split the draws between diverging and not), "
              "the generating model (long runs) between "
              + (f"{crit['generating_grid_interval'][0]:.4g} and "
                 f"{crit['generating_grid_interval'][1]:.4g}"
                 if crit["generating_grid_interval"] is not None else "— (not found in the scan)")
              + f"; controller A has Kd {SETTING_A.kd}.", "",
              "| controller A, mu 12.3 | amplitude (mrad), median [90 %] | frequency (rad/s) | "
              "oscillate | diverge | DF of the median model | generating model (long run) |",
              "|---|---|---|---|---|---|---|"]
    lead, notch = summary["lead"], summary["notch"]
    for label, d in (("plain PD", summary["plain_pd"]),
                     (f"lead {lead['zero']:g}/{lead['example_pole']:g} rad/s", lead["example"]),
                     ("PD + bending", notch["pd_with_bending"]),
                     (f"PD + bending + notch (damping {notch['example_damping']:g}, depth "
                      f"{notch['depth']:g})", notch["example"])):
        lines.append(f"| {label} | {_fmt_q(d['amplitude'], 1e3)} | {_fmt_q(d['frequency'])} | "
                     f"{100 * d['fraction_oscillating']:.0f} %"
                     + (f" ({100 * d['fraction_not_settled']:.0f} % not settled)"
                        if d.get("fraction_not_settled") else "") + " | "
                     f"{100 * d['fraction_diverging']:.0f} % | {_df(d)} | {_gen(d)} |")
    des = summary["design"]
    lines += ["", f"Next experiment ({des['draws']} draws, {des['truths']} hypothetical truths; "
              f"parameters {', '.join(des['params'])}): best **{des['best']}**"
              f"{' (a repeat)' if des['best_is_repeat'] else ' (not a repeat of a tested one)'}.",
              "", "| candidate | tested? | information gain (nats) | "
              + " | ".join(f"{p} width after/before" for p in des["params"]) + " |",
              "|---|---|---|" + "---|" * len(des["params"])]
    for r in des["ranking"]:
        lines.append(f"| {r['name']} | {'yes' if r['tested'] else 'no'} | "
                     f"{r['information_gain']:.3g} | "
                     + " | ".join(f"{r['shrinkage'][p]:.3f}" for p in des["params"]) + " |")
    t = summary["timings"]
    lines += ["", "Time: " + ", ".join(f"{k} {v:.0f} s" for k, v in t.items()) + ".", ""]
    return lines
