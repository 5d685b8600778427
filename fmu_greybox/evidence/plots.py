"""Evidence figures of a validation: residuals with the uncertainty band, zooms, calibration.

Colours as the paper's Figures 3 and 4 (white-box red, recording dotted blue, grey-box green).
Curves that would hide one another are not overlaid: each stage gets a residual panel
(recording minus grey-box, with the grey-box's ±1.96σ band about zero, so the band is drawn at
the scale of the error it describes) and a zoom on the short window where that residual is
largest. Legends sit above the panels, never on them. Written as PNG (atomically) or embedded.
"""

from __future__ import annotations

import io
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib import ticker
from scipy.stats import norm

from fmu_greybox.atomic import atomic_write
from fmu_greybox.evidence.spectra import MIN_COHERENCE, FrequencyResponse
from fmu_greybox.model.calibration import Z95, coverage

WB_STYLE = {"color": "tab:red", "lw": 1.0, "label": "white-box"}
REC_STYLE = {"color": "tab:blue", "lw": 1.2, "ls": ":", "label": "recording"}
GB_STYLE = {"color": "tab:green", "lw": 1.0, "label": "grey-box"}
BAND_STYLE = {"color": "tab:green", "alpha": 0.25, "lw": 0, "label": "grey-box ±1.96σ"}
#: In a zoom the three curves often lie on one another: the white-box dashed, the grey-box
#: wider and solid, the recording as dots, so each shows where they coincide.
ZOOM_STYLES = {
    "white-box": {"color": "tab:red", "lw": 1.0, "ls": "--"},
    "recording": {"color": "tab:blue", "ls": "none", "marker": "o", "ms": 2.5},
    "grey-box": {"color": "tab:green", "lw": 2.2, "alpha": 0.8},
}
#: Most dots a zoom draws of the recording (every row of a 0.2 s window would be a line).
ZOOM_DOTS = 40
#: Shading of the times the correctors were outside their domain (``out_of_domain``).
OUTSIDE_STYLE = {"color": "0.6", "alpha": 0.3, "lw": 0}
#: Share of the residual panel's height the band and the grey-box residual fill at most.
PANEL_MARGIN = 1.3


#: Points a long trace is drawn with at most (:func:`envelope`): two per pixel column of the
#: widest panel at the reports' resolution, so that the thinning cannot be seen.
DRAWN_POINTS = 4000


def envelope(x: np.ndarray, y: np.ndarray, points: int = DRAWN_POINTS) -> tuple:
    """A long trace thinned for drawing without changing how it looks: the samples cut into
    ``points // 2`` runs of consecutive ones, each run drawn by its smallest and its largest
    value, in time order. A line drawn through them covers the same pixels as the whole trace
    at any width of ``points // 2`` pixels or fewer, and drawing costs no more for a 10-minute
    recording than for a 10-second one.

    Parameters
    ----------
    x, y : ndarray, shape (n,)
    points : int

    Returns
    -------
    x, y : ndarray, shape (at most ``points``,)
        The input itself when ``n <= points``.
    """
    n = y.size
    if n <= points:
        return x, y
    runs = points // 2
    width = -(-n // runs)  # ceil
    padded = np.concatenate([y, np.full(runs * width - n, y[-1])]).reshape(runs, width)
    start = np.arange(runs)[:, None] * width
    ends = np.sort(
        np.column_stack([np.argmin(padded, axis=1), np.argmax(padded, axis=1)]) + start, axis=1
    )
    keep = np.minimum(ends.ravel(), n - 1)
    return x[keep], y[keep]


def band_envelope(
    x: np.ndarray, low: np.ndarray, high: np.ndarray, points: int = DRAWN_POINTS
) -> tuple:
    """A long band ``[low, high]`` thinned for drawing (:func:`envelope`): each run of
    consecutive samples by its first time, the smallest ``low`` and the largest ``high``, to be
    drawn as steps (``fill_between(..., step="post")``), so that it holds every sample.

    Returns
    -------
    x, low, high : ndarray, shape (at most ``points // 2 + 1``,)
    """
    n = x.size
    if n <= points:
        return x, low, high
    runs = points // 2
    edges = np.linspace(0, n, runs + 1).astype(int)
    starts = edges[:-1]
    x_out = np.append(x[starts], x[-1])
    low_out = np.minimum.reduceat(low, starts)
    high_out = np.maximum.reduceat(high, starts)
    return x_out, np.append(low_out, low_out[-1]), np.append(high_out, high_out[-1])


def trace_figure(
    time: np.ndarray,
    recorded: np.ndarray,
    whitebox: np.ndarray,
    mean: np.ndarray,
    std: np.ndarray,
    names: Sequence[str],
    units: Sequence[str],
    zoom_seconds: float = 0.2,
    outside: np.ndarray | None = None,
    model_label: str = "grey-box",
) -> plt.Figure:
    """Per stage, the residual with the model's ±1.96σ band, and a zoom on its worst window.

    Left: recording minus grey-box inside the band, titled with both models' RMSE (the
    white-box's residual is often orders of magnitude larger and would hide the band). Right:
    the recording (dots), the white-box (dashed) and the grey-box (wide) with its band over the
    ``zoom_seconds`` window where the grey-box's residual is largest in RMS
    (:data:`ZOOM_STYLES`).

    Parameters
    ----------
    time : ndarray, shape (m,)
    recorded, whitebox, mean, std : ndarray, shape (m, Q)
    names, units : sequence of str, length Q
    zoom_seconds : float
        Length of each zoomed window [s].
    outside : ndarray of bool, shape (m,), optional
        The rows where the correctors were outside their domain: shaded grey behind each
        residual (no calibration vouches for the band there).
    model_label : str
        What the model is, in words (``"grey-box"``; ``"white-box + named terms"`` for a model
        without an active corrector: :attr:`~fmu_greybox.model.store.GreyBoxModel.kind`).

    Returns
    -------
    matplotlib.figure.Figure
    """
    shaded = outside is not None and bool(np.any(outside))
    q_count = len(names)
    fig, axes = plt.subplots(
        q_count,
        2,
        figsize=(11, 2.8 * q_count + 0.6),
        squeeze=False,
        gridspec_kw={"width_ratios": [2.2, 1]},
    )
    dt = float(np.median(np.diff(time))) if time.size > 1 else 1.0
    width = max(2, min(time.size, round(zoom_seconds / dt)))
    for q, (left, right) in enumerate(axes):
        residual = recorded[:, q] - mean[:, q]
        if shaded:
            left.fill_between(
                time, 0, 1, where=outside, transform=left.get_xaxis_transform(), **OUTSIDE_STYLE
            )
        band = band_envelope(time, -Z95 * std[:, q], Z95 * std[:, q])
        left.fill_between(*band, step="post", **BAND_STYLE)
        left.plot(*envelope(time, residual), color="tab:green", lw=0.6)
        reach = np.percentile(np.maximum(np.abs(residual), Z95 * std[:, q]), 99.5)
        left.set_ylim(-PANEL_MARGIN * reach, PANEL_MARGIN * reach)
        inside = coverage(residual, std[:, q], Z95)
        rmse = [np.sqrt(np.mean((recorded[:, q] - m) ** 2)) for m in (whitebox[:, q], mean[:, q])]
        left.set_title(
            f"{names[q]}: recording − model [{units[q]}]\nRMSE white-box {rmse[0]:.3g}, "
            f"{model_label} {rmse[1]:.3g}; {100 * inside:.1f} % inside ±1.96σ",
            fontsize="medium",
            loc="left",
        )
        left.grid(alpha=0.3)
        window = worst_window(residual, width)
        t = time[window]
        right.fill_between(
            t,
            mean[window, q] - Z95 * std[window, q],
            mean[window, q] + Z95 * std[window, q],
            **BAND_STYLE,
        )
        right.plot(t, mean[window, q], **ZOOM_STYLES["grey-box"])
        right.plot(t, whitebox[window, q], **ZOOM_STYLES["white-box"])
        right.plot(
            t,
            recorded[window, q],
            markevery=max(1, t.size // ZOOM_DOTS),
            **ZOOM_STYLES["recording"],
        )
        low = np.minimum(recorded[window, q], mean[window, q] - Z95 * std[window, q]).min()
        high = np.maximum(recorded[window, q], mean[window, q] + Z95 * std[window, q]).max()
        low, high, clipped = zoom_range(low, high, whitebox[window, q])
        right.set_ylim(low, high)
        if clipped:
            right.text(0.01, 0.02, clipped, transform=right.transAxes, fontsize="small")
        right.set_title(f"zoom: largest residual [{units[q]}]", fontsize="medium", loc="left")
        right.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("time [s]")
    handles = [
        plt.Rectangle((0, 0), 1, 1, **{k: v for k, v in BAND_STYLE.items() if k != "label"}),
        plt.Line2D([], [], **ZOOM_STYLES["grey-box"]),
        plt.Line2D([], [], **ZOOM_STYLES["white-box"]),
        plt.Line2D([], [], **ZOOM_STYLES["recording"]),
    ]
    labels = [
        f"{model_label} ±1.96σ",
        f"{model_label} (left: recording − model)",
        "white-box",
        "recording",
    ]
    if shaded:
        handles.append(plt.Rectangle((0, 0), 1, 1, **OUTSIDE_STYLE))
        labels.append("correctors outside their domain")
    legend_above(fig, handles, labels)
    return fig


#: How far beyond the recording and the band (in their spans) a zoom stretches to show the
#: white-box whole; beyond it, the band would shrink to a line, so the white-box is cut and
#: the cut is said on the panel.
WHITEBOX_REACH = 3.0


def zoom_range(low: float, high: float, whitebox: np.ndarray) -> tuple[float, float, str]:
    """A zoom's y-limits: the recording and the band [``low``, ``high``], stretched to hold the
    white-box (shape (w,)) unless that would squash them; then the third value says where the
    white-box went (else it is empty)."""
    span = high - low or abs(high) * 1e-3 or 1.0
    wb_low, wb_high = float(np.min(whitebox)), float(np.max(whitebox))
    clipped = ""
    if wb_low >= low - WHITEBOX_REACH * span and wb_high <= high + WHITEBOX_REACH * span:
        low, high = min(low, wb_low), max(high, wb_high)
    else:
        side = "above" if wb_low > high else "below" if wb_high < low else "around"
        clipped = f"white-box off scale {side}: {span_text(wb_low, wb_high)}"
    pad = 0.1 * (high - low) or span * 0.1
    return low - pad, high + pad, clipped


def span_text(low: float, high: float) -> str:
    """A range in as many significant digits as tell its ends apart (3 to 8), e.g.
    ``0.024512 to 0.024538``; ``constant at 0.0245`` when even 8 do not."""
    for digits in range(3, 9):
        a, b = f"{low:.{digits}g}", f"{high:.{digits}g}"
        if a != b:
            return f"{a} to {b}"
    return f"constant at {low:.3g}"


def worst_window(residual: np.ndarray, width: int) -> slice:
    """The ``width`` consecutive rows where ``residual`` has the largest RMS.

    Parameters
    ----------
    residual : ndarray, shape (m,)
    width : int
        Rows per window (at most m).
    """
    energy = np.convolve(residual**2, np.ones(width), mode="valid")
    start = int(np.argmax(energy))
    return slice(start, start + width)


#: Below this share at every level, a stage's σ before calibration would lie on the axis: it is
#: said in words instead of drawn.
FLAT_SHARE = 0.05


def calibration_figure(
    recorded: np.ndarray,
    mean: np.ndarray,
    std: np.ndarray,
    latent_std: np.ndarray,
    names: Sequence[str],
) -> plt.Figure:
    """Calibration: for each central level p, the share of rows inside ±z_p σ.

    A calibrated σ lies on the diagonal; the target at 95 % (0.90 .. 0.99) is marked. Dashed:
    the propagated σ before calibration, for the stages where it held a visible share
    (:data:`FLAT_SHARE`) at some level; the others are named under the legend with the most
    it held (a σ many times too small holds nothing, a line on the axis).

    Parameters
    ----------
    recorded, mean, std, latent_std : ndarray, shape (m, Q)
    names : sequence of str, length Q
    """
    levels = np.linspace(0.02, 0.995, 60)
    widths = norm.ppf(0.5 + levels / 2)
    fig, ax = plt.subplots(figsize=(8.5, 4.6))
    ax.plot([0, 1], [0, 1], color="0.5", lw=0.8, label="calibrated")
    ax.plot([0.95, 0.95], [0.90, 0.99], color="k", lw=4, alpha=0.35, label="target at 95 %")
    flat = []
    for q, name in enumerate(names):
        residual = recorded[:, q] - mean[:, q]
        share = [coverage(residual, std[:, q], w) for w in widths]
        ax.plot(levels, share, color=f"C{q}", lw=1.2, label=name)
        before = [coverage(residual, latent_std[:, q], w) for w in widths]
        if max(before) >= FLAT_SHARE:
            ax.plot(levels, before, ls="--", color=f"C{q}", lw=1.2, label=f"{name}, before")
        else:
            flat.append(f"{name} (at most {100 * max(before):.2g} %)")
    ax.set_xlabel("nominal share inside ±z σ")
    ax.set_ylabel("share of validation rows inside")
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1.02)
    ax.grid(alpha=0.3)
    legend = ax.legend(
        fontsize="x-small", loc="upper left", bbox_to_anchor=(1.02, 1.0), borderaxespad=0
    )
    legend.set_title("dashed: σ before calibration", prop={"size": "x-small"})
    if flat:
        ax.text(
            1.02,
            0.0,
            "Before calibration, held\nalmost nothing (not drawn):\n" + "\n".join(flat),
            transform=ax.transAxes,
            fontsize="x-small",
            va="bottom",
            gid="flat before calibration",
        )
    fig.tight_layout()
    return fig


def frequency_figure(
    responses: Sequence[FrequencyResponse],
    bands: Sequence[tuple[float, float]],
    model_label: str = "grey-box",
) -> plt.Figure:
    """Per stage (one titled row): gain and phase of recording, white-box and grey-box, and
    coherences, over the frequencies where the recording's estimate is trusted.

    The recording's 95 % bounds are shaded blue, each stage's acceptance band grey. The
    coherence panel shows the recording's input-output coherence (dotted; below the dash-dot
    line at :data:`~fmu_greybox.evidence.spectra.MIN_COHERENCE` a frequency is not trusted), each
    model's coherence with the recording, and as a dashed segment across the band its median
    there: the statistic the tables give (``gid`` ``band median SOURCE``).

    Parameters
    ----------
    responses : sequence of FrequencyResponse
    bands : sequence of (float, float)
        Each stage's band [Hz].
    model_label : str
        What the model is, in words (:func:`trace_figure`).
    """
    styles = {
        "recording": REC_STYLE,
        "white-box": WB_STYLE,
        "grey-box": {**GB_STYLE, "label": model_label},
    }
    rows = len(responses)
    fig, axes = plt.subplots(rows, 3, figsize=(12, 2.9 * rows + 0.6), squeeze=False)
    for (gain, phase, match), r, band in zip(axes, responses, bands, strict=True):
        f = r.freq
        shown = f > 0
        lower, upper = r.gain_bounds_db()
        reference = r.gain_db("recording")
        drawn = np.isfinite(upper)
        gain.fill_between(
            f,
            np.fmax(lower, reference - 40),
            upper,
            where=drawn,
            color="tab:blue",
            alpha=0.15,
            lw=0,
        )
        rec_phase, half = r.phase_deg("recording"), r.phase_bound_deg()
        phase.fill_between(
            f, rec_phase - half, rec_phase + half, where=drawn, color="tab:blue", alpha=0.15, lw=0
        )
        for source in r.response:
            style = styles.get(source, {"label": source})
            gain.semilogx(f[shown], r.gain_db(source)[shown], **style)
            phase.semilogx(f[shown], r.phase_deg(source)[shown], **style)
        match.semilogx(f[shown], r.coherence["recording"][shown], **REC_STYLE)
        match.axhline(MIN_COHERENCE, color="0.4", lw=0.8, ls="-.")
        for source, c in r.match.items():
            style = styles.get(source, {"label": source})
            match.semilogx(f[shown], np.where(r.trusted, c, np.nan)[shown], **style)
            stats = r.band_statistics(source, band)
            if stats.bins:
                trusted = f[r.in_band(band)]
                match.hlines(
                    stats.median_coherence,
                    trusted.min(),
                    trusted.max(),
                    colors=style.get("color"),
                    linestyles="--",
                    lw=1.6,
                    gid=f"band median {source}",
                )
        for ax in (gain, phase, match):
            ax.axvspan(max(band[0], f[shown].min()), band[1], color="0.6", alpha=0.15, lw=0)
            ax.grid(alpha=0.3, which="both")
        gain.set_title(
            f"{r.stage}: {r.output_name} / {r.input_name}", loc="left", fontsize="medium"
        )
        gain.set_ylabel(f"gain [{r.gain_unit}]")
        phase.set_ylabel("phase [deg]")
        match.set_ylabel("coherence")
        match.set_ylim(0, 1.05)
        for ax in (gain, phase, match):
            frequency_ticks(ax)
    for ax in axes[-1]:
        ax.set_xlabel("frequency [Hz]")
    handles = [
        plt.Line2D([], [], **{k: v for k, v in s.items() if k != "label"}) for s in styles.values()
    ] + [
        plt.Rectangle((0, 0), 1, 1, color="tab:blue", alpha=0.15, lw=0),
        plt.Rectangle((0, 0), 1, 1, color="0.6", alpha=0.15, lw=0),
        plt.Line2D([], [], color="k", ls="--", lw=1.6),
        plt.Line2D([], [], color="0.4", ls="-.", lw=0.8),
    ]
    labels = [
        *styles,
        "recording's 95 % bounds",
        "acceptance band",
        "median in the band",
        f"trusted above {MIN_COHERENCE:g}",
    ]
    legend_above(fig, handles, labels)
    return fig


#: Most labelled ticks on a frequency axis, and on a gain or phase axis.
MAX_FREQUENCY_TICKS = 5
MAX_VALUE_TICKS = 6


def frequency_ticks(ax: plt.Axes) -> None:
    """Few, readable ticks on a panel over frequency: on the log axis, 1-2-5 steps (thinned to
    decades, then to every other decade, until at most :data:`MAX_FREQUENCY_TICKS` remain)
    written in engineering form (``200``, ``1k``), the others unlabelled (a span narrower than
    one step gets two ticks inside it); on the value axis at most :data:`MAX_VALUE_TICKS`
    ticks, without an offset. Matplotlib's own labels every minor
    tick of an axis spanning less than a decade, and they run into one another."""
    low, high = ax.get_xlim()
    decades = np.arange(np.floor(np.log10(low)), np.ceil(np.log10(high)) + 1)
    for steps, stride in (((1, 2, 5), 1), ((1,), 1), ((1,), 2), ((1,), 3)):
        ticks = [
            step * 10.0**d
            for d in decades[::stride]
            for step in steps
            if low <= step * 10.0**d <= high
        ]
        if len(ticks) <= MAX_FREQUENCY_TICKS:
            break
    if len(ticks) < 2:  # narrower than one 1-2-5 step: two ticks inside, 2 digits
        ticks = sorted({float(f"{v:.2g}") for v in np.geomspace(low, high, 4)[1:3]})
    ax.xaxis.set_major_locator(ticker.FixedLocator(ticks))
    ax.xaxis.set_major_formatter(ticker.EngFormatter(sep=""))
    ax.xaxis.set_minor_formatter(ticker.NullFormatter())
    ax.yaxis.set_major_locator(ticker.MaxNLocator(MAX_VALUE_TICKS))
    ax.yaxis.get_major_formatter().set_useOffset(False)


def legend_above(fig: plt.Figure, handles: list, labels: list[str]) -> None:
    """One legend for the figure, above its panels; the panels are laid out below it."""
    fig.legend(
        handles, labels, loc="upper center", ncol=len(labels), fontsize="small", frameon=False
    )
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.35 / fig.get_figheight()))


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
