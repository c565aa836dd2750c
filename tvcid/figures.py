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
