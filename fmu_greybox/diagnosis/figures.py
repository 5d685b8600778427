"""Evidence figures of a diagnosis (matplotlib, Agg backend).

* residual versus time per stage, in units of sensor noise, before and after the named terms,
  with the windows of most residual energy shaded;
* residual by regime: share of the energy against share of the time per regime and band;
* before/after traces on the held-out rows: recording, white-box, white-box + named terms,
  grey-box.
"""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from fmu_greybox.evidence.plots import GB_STYLE, REC_STYLE, WB_STYLE, envelope

NAMED_STYLE = {"color": "tab:purple", "lw": 1.0, "label": "white-box + named terms"}


def residual_figure(diagnosis) -> plt.Figure:
    """Noise-normalised residual of every stage target versus time, before and after."""
    exp = diagnosis.experiment_
    observed = diagnosis.signals_.observed
    targets = [j for j, s in enumerate(observed) if s.is_target]
    time = exp.start_time + exp.dt * np.arange(exp.n_samples)
    wb = exp.residual(diagnosis.simulated_["whitebox"])
    named = exp.residual(diagnosis.simulated_["named"])
    stages = diagnosis.locator_.stages_
    fig, axes = plt.subplots(len(targets), 1, figsize=(10, 2.2 * len(targets)), squeeze=False)
    for ax, j in zip(axes[:, 0], targets, strict=True):
        sig = observed[j]
        stage = stages[sig.stage]
        for regime in stage.signals[0].regimes if stage.signals else []:
            if regime.span is not None:
                ax.axvspan(*regime.span, color="orange", alpha=0.15, lw=0)
        ax.plot(*envelope(time, wb[:, j]), color="tab:red", lw=0.8, label="white-box")
        ax.plot(*envelope(time, named[:, j]), color="tab:purple", lw=0.8, label="with named terms")
        ax.axvline(time[exp.train_rows], color="k", ls="--", lw=0.8)
        ax.set_ylabel(f"{stage.name}\n{sig.name} / noise")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize="small", ncol=2)
    axes[0, 0].set_title(
        "Residual in units of sensor noise (shaded: most energetic windows; dashed: held-out "
        "starts)",
        fontsize="medium",
    )
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    return fig


def regime_figure(diagnosis) -> plt.Figure:
    """Energy share against time share of the regimes, per stage, for the stage's signal
    furthest above noise (bands: against the share of the bandwidth)."""
    stages = [s for s in diagnosis.locator_.stages_ if s.signals]
    fig, axes = plt.subplots(len(stages), 1, figsize=(10, 2.8 * len(stages)), squeeze=False)
    for ax, stage in zip(axes[:, 0], stages, strict=True):
        signal = max(stage.signals, key=lambda s: s.noise_ratio)
        regimes = [r for r in signal.regimes if r.kind != "window"]
        y = np.arange(len(regimes))
        ax.barh(
            y - 0.2,
            [r.time_share for r in regimes],
            0.4,
            color="0.7",
            label="share of time (bands: of bandwidth)",
        )
        ax.barh(
            y + 0.2,
            [r.energy_share for r in regimes],
            0.4,
            color="tab:red",
            label="share of residual energy",
        )
        ax.set_yticks(y, [f"{r.kind}: {r.label}" for r in regimes], fontsize="x-small")
        ax.invert_yaxis()
        ax.set_title(
            f"{stage.name}: {signal.name} (residual {signal.noise_ratio:.3g} x noise)",
            fontsize="medium",
        )
        ax.grid(alpha=0.3, axis="x")
    axes[0, 0].legend(loc="lower right", fontsize="small")
    fig.tight_layout()
    return fig


def trace_figure(diagnosis) -> plt.Figure:
    """Held-out traces per stage: recording, white-box, named terms and, when trained, the
    grey-box."""
    exp = diagnosis.experiment_
    observed = diagnosis.signals_.observed
    targets = [j for j, s in enumerate(observed) if s.is_target]
    rows = slice(exp.train_rows, exp.n_samples)
    time = exp.start_time + exp.dt * np.arange(exp.n_samples)[rows]
    gb = diagnosis.simulated_.get("greybox")  # None: no grey-box was trained
    fig, axes = plt.subplots(len(targets), 1, figsize=(10, 2.4 * len(targets)), squeeze=False)
    for q, (ax, j) in enumerate(zip(axes[:, 0], targets, strict=True)):
        sig = observed[j]
        ax.plot(*envelope(time, diagnosis.simulated_["whitebox"][rows, j]), **WB_STYLE)
        ax.plot(*envelope(time, exp.recorded[rows, j]), **REC_STYLE)
        ax.plot(*envelope(time, diagnosis.simulated_["named"][rows, j]), **NAMED_STYLE)
        if gb is not None and q < gb.shape[1]:
            ax.plot(*envelope(time, gb[:, q]), **GB_STYLE)
        ax.set_ylabel(f"{diagnosis.signals_.stage_names[sig.stage]}\n{sig.name} [{sig.unit}]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(loc="upper right", fontsize="small", ncol=4)
    axes[0, 0].set_title("Held-out rows: before and after", fontsize="medium")
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    return fig
