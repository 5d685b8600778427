"""Draw docs/img/architecture.png, the data flow of fmu-greybox by subpackage.

Run: .venv/bin/python docs/img/architecture.py
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from matplotlib.patches import FancyArrowPatch, FancyBboxPatch

#: Box name -> (x, y, subpackage, what it holds).
BOXES = {
    "recordings": (0.0, 2.0, "data/", "Recording: CSV, Parquet,\nMAT, MDF4; units, grid"),
    "fmu": (0.0, 0.0, "fmi/", "white-box FMU: archive,\ninstance, binding, build"),
    "project": (2.2, 1.0, "project/", "project file, signals,\nstages; prepared data"),
    "model": (4.4, 1.0, "model/", "named terms, white-box\nstepping, chain, store"),
    "gp": (4.4, -0.6, "gp/", "sparse GP (VFE),\nchain step in C"),
    "diagnosis": (4.4, 2.6, "diagnosis/", "locate, name, model,\nshow: findings"),
    "workflow": (6.6, 1.0, "workflow/", "train, master, validate,\nmetrics, parts"),
    "export": (8.8, 0.2, "export/", "grey-box FMU, SSP\nbench, FMU runtime"),
    "report": (8.8, 1.8, "report/", "the demo, HTML reports\n(plots: evidence/)"),
    "synth": (0.0, 3.6, "synth/", "truth model in closed\nloop: recordings"),
    "campaign": (8.8, 3.4, "campaign/", "many recordings on\nDask: trends, drift"),
}
ARROWS = [
    ("synth", "recordings"),
    ("recordings", "project"),
    ("fmu", "project"),
    ("project", "model"),
    ("project", "diagnosis"),
    ("diagnosis", "model"),
    ("gp", "model"),
    ("model", "workflow"),
    ("workflow", "export"),
    ("workflow", "report"),
    ("diagnosis", "report"),
    ("diagnosis", "campaign"),
    ("campaign", "report"),
]
W, H = 1.8, 0.9


def _ends(a: tuple, b: tuple) -> tuple[tuple[float, float], tuple[float, float]]:
    """Arrow from box ``a`` to box ``b``: edge to facing edge."""
    (xa, ya, *_), (xb, yb, *_) = a, b
    if abs(xb - xa) < 0.1:  # one above the other
        if yb > ya:
            return (xa + W / 2, ya + H + 0.05), (xb + W / 2, yb - 0.05)
        return (xa + W / 2, ya - 0.05), (xb + W / 2, yb + H + 0.05)
    return (xa + W + 0.05, ya + H / 2), (xb - 0.05, yb + H / 2)


def main() -> None:
    fig, ax = plt.subplots(figsize=(11, 5))
    for x, y, package, text in BOXES.values():
        ax.add_patch(
            FancyBboxPatch((x, y), W, H, boxstyle="round,pad=0.05", fc="#eef3fb", ec="#3b5b92")
        )
        ax.text(x + W / 2, y + H - 0.18, package, ha="center", fontsize=11, weight="bold")
        ax.text(x + W / 2, y + 0.33, text, ha="center", va="center", fontsize=8)
    for a, b in ARROWS:
        ax.add_patch(
            FancyArrowPatch(
                *_ends(BOXES[a], BOXES[b]),
                arrowstyle="-|>",
                mutation_scale=14,
                color="#555",
                shrinkA=4,
                shrinkB=4,
            )
        )
    ax.set_xlim(-0.3, 10.9)
    ax.set_ylim(-0.9, 4.7)
    ax.axis("off")
    ax.set_title("fmu-greybox: recordings and a white-box FMU in, a grey-box FMU and evidence out")
    out = Path(__file__).with_name("architecture.png")
    fig.savefig(out, dpi=110, bbox_inches="tight")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
