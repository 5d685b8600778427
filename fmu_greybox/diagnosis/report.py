"""What a diagnosis writes: ``diagnosis.json`` (versioned schema) and a self-contained HTML report.

The schema is documented in ``docs/diagnosis.md``; :data:`SCHEMA_VERSION` changes whenever a
field changes meaning or disappears (adding fields keeps the version). The HTML report embeds
its figures as base64 PNGs, so it can be mailed or filed as one file: verdict first, then the
findings, the before/after table and the evidence plots.
"""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path

import numpy as np

from .. import __version__
from ..atomic import atomic_write
from ..plots import png_bytes
from .figures import regime_figure, residual_figure, trace_figure

SCHEMA_VERSION = 1


def diagnosis_payload(diagnosis, recording) -> dict:
    """The content of ``diagnosis.json``.

    Parameters
    ----------
    diagnosis : Diagnosis
        A fitted diagnosis.
    recording : Recording
        The recording it was fitted on.
    """
    exp = diagnosis.experiment_
    findings = [f.to_dict() for f in diagnosis.findings_]
    origin = diagnosis.origin_stage_
    named = [f for f in diagnosis.findings_ if f.effect not in ("none", "unexplained")]
    selection = diagnosis.selection_
    return {
        "schema_version": SCHEMA_VERSION,
        "tool": f"fmu-greybox {__version__}",
        "project": diagnosis.config.name,
        "config": str(diagnosis.config.path) if diagnosis.config.path else None,
        "fmu": str(diagnosis.fmu_path_),
        "recording": {
            "source": str(recording.source),
            "sha256": recording.sha256(),
            "n_samples": recording.n_samples,
            "dt": recording.dt,
            "train_rows": exp.train_rows,
            "heldout_rows": exp.n_samples - exp.train_rows,
        },
        "verdict": verdict_lines(diagnosis),
        "origin_stage": origin,
        "origin_consistent": (not named) or named[0].stage == origin,
        "stages": [s.to_dict() for s in diagnosis.locator_.stages_],
        "findings": findings,
        "fit": diagnosis.fit_,
        "hypotheses_tested": [h.key for h in diagnosis.hypotheses_],
        "selection": [
            {"screened": r.screened, "refined": r.refined, "accepted": r.accepted}
            for r in (selection.rounds_ if selection is not None else [])
        ],
        "simulations": diagnosis.simulations_,
        "timings": diagnosis.timings_,
    }


def verdict_lines(diagnosis) -> list[str]:
    """The verdict in a few lines of text (what the terminal prints)."""
    lines = []
    stages = diagnosis.locator_.stages_
    if diagnosis.origin_stage_ is None:
        lines.append("No significant mismatch: every stage matches within sensor noise.")
    else:
        before = [s.name for s in stages if stages.index(s) < diagnosis.locator_.origin_]
        matched = f" ({', '.join(before)} match{'es' if len(before) == 1 else ''} within noise)"
        lines.append(
            f"Mismatch starts in stage {diagnosis.origin_stage_}{matched if before else ''}."
        )
    for i, finding in enumerate(diagnosis.findings_, 1):
        if finding.effect == "none":
            continue
        lines.append(f"{i}. [{finding.stage}] {finding.effect}: {finding.summary}")
    for name, row in diagnosis.fit_.items():
        unit = row["unit"]
        lines.append(
            f"   {name}: held-out RMSE white-box {row['wb_rmse']:.3g} -> named "
            f"{row['named_rmse']:.3g} -> grey-box {row['gb_rmse']:.3g} {unit}"
        )
    return lines


def write_outputs(diagnosis, recording, out_dir: str | Path) -> dict:
    """Write ``diagnosis.json`` and ``report.html`` into ``out_dir`` (created if needed).

    Each file is written atomically. Returns the JSON payload.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    payload = diagnosis_payload(diagnosis, recording)
    with atomic_write(out / "diagnosis.json") as f:
        json.dump(_plain(payload), f, indent=2, allow_nan=False)
        f.write("\n")
    with atomic_write(out / "report.html") as f:
        f.write(report_html(diagnosis, payload))
    return payload


def report_html(diagnosis, payload: dict) -> str:
    """The self-contained HTML report."""
    esc = html.escape
    figures = [
        ("Residual versus time", residual_figure(diagnosis)),
        ("Residual by regime and frequency band", regime_figure(diagnosis)),
        ("Before and after on held-out data", trace_figure(diagnosis)),
    ]
    parts = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>Diagnosis of {esc(payload['project'])}</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto;}"
        "table{border-collapse:collapse;margin:1em 0;}td,th{border:1px solid #bbb;"
        "padding:4px 8px;text-align:left;font-size:90%;}.verdict{background:#f4f4f4;"
        "padding:1em;border-left:4px solid #555;}img{max-width:100%;}</style></head><body>",
        f"<h1>Diagnosis of {esc(payload['project'])}</h1>",
        "<div class='verdict'><h2>Verdict</h2>",
        *(f"<p>{esc(line)}</p>" for line in payload["verdict"]),
        "</div>",
        "<h2>Findings</h2><table><tr><th>#</th><th>stage</th><th>effect</th><th>magnitude</th>"
        "<th>95 % interval</th><th>explained</th><th>summary</th></tr>",
    ]
    for i, f in enumerate(payload["findings"], 1):
        mag = f.get("magnitude") or {}
        value = f"{mag['value']:.4g} {mag.get('unit', '')}" if "value" in mag else ""
        ci = mag.get("ci95")
        interval = f"[{ci[0]:.4g}, {ci[1]:.4g}]" if ci else ""
        explained = f.get("explained_fraction")
        share = f"{100 * explained:.0f} %" if explained is not None else ""
        parts.append(
            f"<tr><td>{i}</td><td>{esc(str(f['stage']))}</td><td>{esc(f['effect'])}</td>"
            f"<td>{esc(value)}</td><td>{esc(interval)}</td><td>{share}</td>"
            f"<td>{esc(f['summary'])}</td></tr>"
        )
    parts.append("</table>")
    parts.append(
        "<h2>Fit on held-out data</h2><table><tr><th>stage</th><th>unit</th><th>noise</th>"
        "<th>white-box RMSE</th><th>+ named terms</th><th>grey-box</th></tr>"
    )
    for name, row in payload["fit"].items():
        parts.append(
            f"<tr><td>{esc(name)}</td><td>{esc(row['unit'])}</td><td>{row['noise']:.3g}</td>"
            f"<td>{row['wb_rmse']:.3g}</td>"
            f"<td>{row['named_rmse']:.3g} ({100 * row['named_improvement']:+.0f} %)</td>"
            f"<td>{row['gb_rmse']:.3g} ({100 * row['gb_improvement']:+.0f} %)</td></tr>"
        )
    parts.append("</table>")
    parts.append(
        "<h2>Residual per stage (white-box)</h2><table><tr><th>stage</th><th>signal</th>"
        "<th>RMS</th><th>RMS / noise</th><th>nRMS</th><th>inherited</th></tr>"
    )
    for stage in payload["stages"]:
        for sig in stage["signals"]:
            parts.append(
                f"<tr><td>{esc(stage['stage'])}</td><td>{esc(sig['signal'])}</td>"
                f"<td>{sig['rms']:.3g} {esc(sig['unit'])}</td><td>{sig['noise_ratio']:.3g}</td>"
                f"<td>{sig['nrms']:.3g}</td>"
                f"<td>{100 * stage['inherited_fraction']:.0f} %</td></tr>"
            )
    parts.append("</table>")
    for title, fig in figures:
        data = base64.b64encode(png_bytes(fig)).decode("ascii")
        parts.append(
            f"<h2>{esc(title)}</h2><img alt='{esc(title)}' src='data:image/png;base64,{data}'>"
        )
    parts.append(
        f"<p><small>{esc(payload['tool'])}; recording {esc(payload['recording']['source'])} "
        f"(sha256 {payload['recording']['sha256'][:12]}); FMU {esc(payload['fmu'])}; "
        f"{payload['simulations']} simulations in {payload['timings'].get('total', 0)} s."
        "</small></p></body></html>"
    )
    return "\n".join(parts)


def _plain(value):
    """JSON-safe copy: numpy scalars to Python, non-finite floats to None."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (np.floating, float)):
        value = float(value)
        return value if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
