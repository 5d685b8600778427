"""Figures in the style of the paper's Figures 3 and 4.

White-box in red, recording dotted blue, grey-box in green with its ±2σ band; one panel per
stage plus a zoom on a short window of the first stage. Written as PNG (atomically).
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from fmu_greybox.atomic import atomic_write

WB_STYLE = {"color": "tab:red", "lw": 1.0, "label": "white-box"}
REC_STYLE = {"color": "tab:blue", "lw": 1.2, "ls": ":", "label": "recording"}
GB_STYLE = {"color": "tab:green", "lw": 1.0, "label": "grey-box"}


def trace_figure(
    time: np.ndarray,
    recorded: np.ndarray,
    whitebox: np.ndarray,
    mean: np.ndarray,
    std: np.ndarray,
    names: Sequence[str],
    units: Sequence[str],
    zoom_seconds: float = 0.2,
) -> plt.Figure:
    """Stage traces with uncertainty band, and a zoom on the first stage.

    Parameters
    ----------
    time : ndarray, shape (m,)
    recorded, whitebox, mean, std : ndarray, shape (m, Q)
    names, units : sequence of str, length Q
    zoom_seconds : float
        Length of the zoomed window, centred in the run [s].

    Returns
    -------
    matplotlib.figure.Figure
    """
    q_count = len(names)
    fig, axes = plt.subplots(q_count + 1, 1, figsize=(10, 2.4 * (q_count + 1)), squeeze=False)
    for q, ax in enumerate(axes[:q_count, 0]):
        _panel(ax, time, recorded[:, q], whitebox[:, q], mean[:, q], std[:, q])
        ax.set_ylabel(f"{names[q]} [{units[q]}]")
    mid = 0.5 * (time[0] + time[-1])
    window = (time >= mid - zoom_seconds / 2) & (time <= mid + zoom_seconds / 2)
    ax = axes[q_count, 0]
    _panel(
        ax, time[window], recorded[window, 0], whitebox[window, 0], mean[window, 0], std[window, 0]
    )
    ax.set_ylabel(f"{names[0]} [{units[0]}] (zoom)")
    ax.set_xlabel("time [s]")
    axes[0, 0].legend(loc="upper right", ncol=4, fontsize="small")
    fig.tight_layout()
    return fig


def _panel(
    ax: plt.Axes, t: np.ndarray, rec: np.ndarray, wb: np.ndarray, mean: np.ndarray, std: np.ndarray
) -> None:
    ax.fill_between(
        t, mean - 2 * std, mean + 2 * std, color="tab:green", alpha=0.25, lw=0, label="grey-box ±2σ"
    )
    ax.plot(t, wb, **WB_STYLE)
    ax.plot(t, rec, **REC_STYLE)
    ax.plot(t, mean, **GB_STYLE)
    ax.grid(alpha=0.3)


def save_png(fig: plt.Figure, path: str | Path, dpi: int = 110) -> None:
    """Write a figure as PNG atomically and close it."""
    with atomic_write(Path(path), "wb") as f:
        fig.savefig(f, format="png", dpi=dpi)
    plt.close(fig)


def png_bytes(fig: plt.Figure, dpi: int = 110) -> bytes:
    """A figure as PNG bytes (for embedding in HTML); closes the figure."""
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    plt.close(fig)
    return buffer.getvalue()
