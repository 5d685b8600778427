"""``campaign.html``: the campaign on one self-contained page.

Verdict first (how many recordings, which magnitudes drift), then one trend plot per named
magnitude (value with its 95 % interval against recording, the weighted slope), the
per-recording verdict table with links to each recording's own report, and the drift test in
words. Figures are embedded PNGs, as in every report of the package.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from fmu_greybox.atomic import atomic_write
from fmu_greybox.evidence.html import escape, figure, page, table, verdict


def summary_lines(payload: dict) -> list[str]:
    """The campaign's verdict in a few lines (what the terminal prints, atop the page)."""
    s = payload["summary"]
    lines = [
        f"{s['recordings']} recordings: {s['diagnosed']} diagnosed, {s['reused']} reused "
        f"from an earlier run, {s['failed']} failed."
    ]
    for trend in payload["trends"]:
        lines.append(trend_line(trend, s["recordings"]))
    return lines


def trend_line(trend: dict, recordings: int) -> str:
    """One trend in words."""
    what = f"{trend['effect']} {trend['parameter']} [{trend['stage']}]"
    named = f"named in {trend['named_in']} of {recordings}"
    if trend["drift"] is None:
        return f"{what}: {named}; too few intervals to test for drift."
    slope = f"{trend['slope']:+.4g} {trend['unit']} per recording".replace("  ", " ")
    verdict = "DRIFTS" if trend["drift"] else "constant within its intervals"
    p = trend["p_value"]
    chance = f"p = {p:.2g}" if p >= 1e-16 else "p < 1e-16"
    return f"{what}: {verdict} ({chance}, slope {slope}; {named})."


def trend_figure(trend: dict, labels: list[str]) -> plt.Figure:
    """Magnitude with its 95 % interval against recording, and the weighted slope.

    Parameters
    ----------
    trend : dict
        An entry of ``campaign.json``'s ``trends``.
    labels : list of str, length n_recordings
        Recording names, in campaign order.
    """
    n = len(labels)
    fig, ax = plt.subplots(figsize=(8, 3.2))
    named = [i for i, v in enumerate(trend["values"]) if v is not None]
    y = np.array([trend["values"][i] for i in named], dtype=float)
    low = np.array([(trend["ci95"][i] or [v, v])[0] for i, v in zip(named, y, strict=True)])
    high = np.array([(trend["ci95"][i] or [v, v])[1] for i, v in zip(named, y, strict=True)])
    # never a negative error bar (matplotlib refuses one), whatever an interval holds
    below, above = np.clip(y - low, 0.0, None), np.clip(high - y, 0.0, None)
    ax.errorbar(named, y, yerr=[below, above], fmt="o", capsize=4, color="tab:blue")
    if trend["slope"] is not None:
        span = np.array([min(named), max(named)], dtype=float)
        line = trend["intercept"] + trend["slope"] * span
        ax.plot(span, line, "--", color="tab:red", lw=1, label="weighted slope")
        ax.legend(loc="best", fontsize=8)
    ax.set_xticks(range(n), labels, rotation=30 if n > 6 else 0, ha="right" if n > 6 else "center")
    ax.set_xlim(-0.5, n - 0.5)
    ax.set_xlabel("recording")
    ax.set_ylabel(f"{trend['parameter']} [{trend['unit'] or '-'}]")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    return fig


def campaign_html(payload: dict) -> str:
    """The self-contained HTML page of a campaign."""
    records = payload["recordings"]
    labels = [Path(r["source"]).stem for r in records]
    n = len(records)
    plots = [
        figure(
            f"{t['effect']} {t['parameter']} [{t['stage']}]",
            trend_figure(t, labels),
            trend_line(t, n),
        )
        for t in payload["trends"]
    ]
    rows = [
        (
            i + 1,
            _link(r),
            escape(r["start_time"] or ""),
            escape(r["status"]),
            escape(_verdict(r)),
            escape(r["worker"] or ""),
            "" if r["seconds"] is None else f"{r['seconds']:.1f}",
        )
        for i, r in enumerate(records)
    ]
    test = payload["drift_test"]
    order = "by start time" if payload["order"] == "start_time" else "in the order given"
    return page(
        f"Campaign of {payload['project']}",
        [
            verdict(summary_lines(payload)),
            "<h2>Trends</h2>" if plots else "<h2>Trends</h2><p>No effect was named.</p>",
            *plots,
            f"<h2>Recordings ({escape(order)})</h2>",
            table(
                ("#", "recording", "start", "status", "verdict", "worker", "seconds [s]"),
                rows,
                raw=True,
            ),
            "<h2>Drift test</h2>",
            f"<p>{escape(test['test'])} (alpha = {test['alpha']}). Slope: {escape(test['slope'])}."
            " A recording that did not name a magnitude has no value and is left out.</p>",
            f"<p><small>{escape(payload['tool'])}; FMU {escape(payload['fmu'])}; scheduler "
            f"{escape(payload['cluster']['scheduler'])} with {payload['cluster']['workers']} "
            f"workers; {payload['summary'].get('wall_seconds', 0)} s.</small></p>",
        ],
    )


def write_page(payload: dict, path: str | Path) -> None:
    """Write ``campaign.html`` atomically."""
    with atomic_write(Path(path)) as f:
        f.write(campaign_html(payload))


def _link(record: dict) -> str:
    name = escape(Path(record["source"]).name)
    if record["report"] is None:
        return name
    return f"<a href='{escape(record['report'])}'>{name}</a>"


def _verdict(record: dict) -> str:
    if record["status"] == "failed":
        return f"failed: {record['error']}"
    return " ".join(record["verdict"][:2])
