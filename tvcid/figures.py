"""Figures the commands and studies write to files (the Agg backend: never a window)."""
from __future__ import annotations


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (studies write files, never open windows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_posterior_figures(post, out_dir, seed=0, n_draws=30):
    """``corner.png``, ``traces.png`` and ``predictive.png`` (one panel per recording) of a
    :class:`tvcid.discovery.calibration.Posterior` into ``out_dir``."""
    plt = pyplot()
    fig = post.plot_corner()
    fig.savefig(out_dir / "corner.png", dpi=90)
    plt.close(fig)
    axes = post.plot_traces()
    axes[0].figure.savefig(out_dir / "traces.png", dpi=90)
    plt.close(axes[0].figure)
    pred = post.predictive(n_draws=n_draws, seed=seed)
    fig, axs = plt.subplots(len(pred.curves), 1, figsize=(8, 2.8 * len(pred.curves)), squeeze=False)
    for ax, name in zip(axs[:, 0], pred.curves):
        pred.plot(name, ax=ax)
    fig.tight_layout()
    fig.savefig(out_dir / "predictive.png", dpi=90)
    plt.close(fig)


def write_pinned_figure(post, pinned, path, recordings=(), params=None, max_panels=6):
    """The draws of one member over the parameters its pinned combinations join, pair by pair
    (``pinned``: :class:`tvcid.discovery.calibration.pinned.PinnedMap` as a dict): each combination's
    leading term against its next two, at most ``max_panels`` panels. Where the dead zone acts on
    the error (paper 002's structure, ``params``: ActuatorParams or a ranking row's dict), the backlash / dead-zone pair carries paper
    002's describing-function family (:func:`tvcid.discovery.calibration.ridge.df_family`), placed by
    the first limit cycle of ``recordings``. Writes ``path`` and returns it, or ``None`` where no
    combination joins two parameters."""
    import textwrap

    import numpy as np
    from matplotlib.ticker import NullFormatter

    from tvcid.discovery.calibration.ridge import df_family
    from tvcid.models.cycle_reading import (
        InsufficientPeriodsError,
        limit_cycle_features,
        robust_amplitude,
    )

    combos = [c for c in pinned["pinned"] if len(c["terms"]) > 1]
    pairs = []
    for c in combos:
        names = list(c["terms"])
        pairs += [(names[0], n) for n in names[1:3] if (names[0], n) not in pairs]
    if isinstance(params, dict):  # a ranking row's parameters
        from tvcid.models import params_from_dict

        params = params_from_dict("custom", params)
    on_error = params is not None and str(getattr(params.dead_zone_position, "value", "")) == "error"
    family = on_error and any({"backlash", "dead_zone"} <= set(c["terms"]) for c in combos)
    if family and not {("backlash", "dead_zone"), ("dead_zone", "backlash")} & set(pairs):
        pairs.insert(0, ("backlash", "dead_zone"))
    pairs = pairs[:max_panels]
    if not pairs:
        return None
    logs = {n: v for c in pinned["pinned"] for n, v in c["logs"].items()}
    plt = pyplot()
    cols = min(len(pairs), 3)
    rows = -(-len(pairs) // cols)
    fig, axs = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.8 * rows), squeeze=False)
    rng = np.random.default_rng(0)
    s = post.samples
    if s.shape[0] > 3000:
        s = s[rng.choice(s.shape[0], 3000, replace=False)]
    cycle = next((r for r in recordings if r.kind == "closed"), None)
    for ax, (a, b) in zip(axs.ravel(), pairs):
        x, y = s[:, post.names.index(a)], s[:, post.names.index(b)]
        ax.plot(x, y, ".", ms=1.5, alpha=0.35, color="C0", label="draws")
        if family and {a, b} == {"backlash", "dead_zone"} and cycle is not None:
            try:
                amplitude = robust_amplitude(cycle.t, cycle.delta)
                frequency = limit_cycle_features(cycle.t, cycle.delta).frequency
                f, zm, source = df_family(amplitude, frequency, cycle.experiment(), params)
                fx, fy = (f, zm) if a == "backlash" else (zm, f)
                ax.plot(fx, fy, "k--", lw=1.2, label="DF family (paper 002)")
                ax.text(0.02, 0.02, source, transform=ax.transAxes, fontsize=5)
            except (InsufficientPeriodsError, ValueError):
                pass
        ax.set_xscale("log" if logs.get(a, True) else "linear")
        ax.set_yscale("log" if logs.get(b, True) else "linear")
        for axis in (ax.xaxis, ax.yaxis):
            axis.set_minor_formatter(NullFormatter())
        ax.tick_params(labelsize=7)
        ax.set_xlabel(a)
        ax.set_ylabel(b)
        ax.legend(fontsize=6)
    for ax in axs.ravel()[len(pairs):]:
        ax.set_visible(False)
    texts = [c["text"] for c in combos]
    fig.suptitle("\n".join(textwrap.wrap("pinned: " + "; ".join(texts), 60 * cols)), fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
