"""Long traces are drawn thinned to their min/max envelope: the same picture at a fraction of
the cost (a 10-minute recording's residual panel would otherwise draw 600 000 points)."""

from __future__ import annotations

import io

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from PIL import Image

from fmu_greybox.evidence.plots import DRAWN_POINTS, band_envelope, envelope


def _picture(x: np.ndarray, y: np.ndarray, limits: tuple[float, float]) -> np.ndarray:
    """A residual panel's size and line at the reports' resolution, in grey levels."""
    fig, ax = plt.subplots(figsize=(7.5, 2.8))
    ax.plot(x, y, color="tab:green", lw=0.6)
    ax.set_xlim(x[0], x[-1])
    ax.set_ylim(*limits)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=110)
    plt.close(fig)
    return np.asarray(Image.open(buffer).convert("L"), dtype=float)


def test_a_thinned_trace_draws_the_same_picture() -> None:
    """30 000 samples of a noisy random walk drawn whole and from the envelope's 4 000 points:
    fewer than 0.5 % of the pixels differ by more than a quarter of the grey range (the line's
    anti-aliased edges), and every run keeps its extremes in time order."""
    rng = np.random.default_rng(0)
    n = 30_000
    x = np.arange(n) * 1e-3
    y = rng.normal(size=n).cumsum() + 3.0 * rng.normal(size=n)
    xe, ye = envelope(x, y)
    assert xe.size <= DRAWN_POINTS and np.all(np.diff(xe) >= 0)
    assert ye.max() == y.max() and ye.min() == y.min()
    limits = (y.min() - 1.0, y.max() + 1.0)
    whole, thinned = _picture(x, y, limits), _picture(xe, ye, limits)
    assert np.mean(np.abs(whole - thinned) > 64) < 0.005
    short = np.arange(10.0)
    assert envelope(short, short)[1] is short  # short traces are drawn as they are


def test_a_thinned_band_holds_the_whole_band() -> None:
    """Each thinned band segment spans at least every sample of its run."""
    rng = np.random.default_rng(1)
    n = 50_001
    x = np.arange(n) * 1e-3
    half = np.abs(rng.normal(size=n)) + 1.0
    xb, low, high = band_envelope(x, -half, half)
    assert xb.size <= DRAWN_POINTS // 2 + 1 and xb[0] == x[0] and xb[-1] == x[-1]
    run = np.searchsorted(xb, x, side="right") - 1
    assert np.all(high[run] >= half) and np.all(low[run] <= -half)
