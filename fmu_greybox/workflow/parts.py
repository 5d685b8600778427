"""Never worse than its parts: named terms alone, correctors alone and both, on held-out rows.

A model with named terms (from a diagnosis) is one of three candidates: the paper's correctors
on the plain white-box (``correctors``), the white-box with the named terms and no corrector
(``terms``), and correctors trained on top of the named terms (``terms+correctors``).
``diagnose`` free-runs each over the rows it holds out and compares them stage by stage.

``train --terms`` compares them forward in time on a longer stretch: correctors trained on the
first half of the training rows, every part free-run from the recording's first row as a bench
runs it (the chain's memory from the recorded outputs of that row only) and scored on every
later row. The last few percent of a recording rarely leave the regimes its training rows
cover; half a recording more often does, and that is where correctors alone, which cannot
extrapolate, fall behind named physics. The model shipped is the best unless the user names
another, and its correctors are then trained on all the training rows.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fmu_greybox.errors import ConfigError
from fmu_greybox.workflow.metrics import rmse

if TYPE_CHECKING:
    from fmu_greybox.model.chain import RecordedRun
    from fmu_greybox.model.store import GreyBoxModel
    from fmu_greybox.project.data import ProjectData

#: The candidates, in the order they are reported.
PARTS = ("correctors", "terms", "terms+correctors")
#: What ``train --ship`` accepts: the best candidate on held-out rows, or one named.
SHIP_CHOICES = ("best", *PARTS)
#: Fewest held-out rows a comparison is made on; with fewer the data cannot decide.
MIN_COMPARED_ROWS = 50
#: A part whose score is within this share of the best part's is reported as equally good: the
#: held-out rows cannot tell them apart (a held-out mean square within about 10 %, the margin
#: the diagnosis uses for competing explanations).
EQUAL_MARGIN = 0.05


@dataclass(frozen=True)
class PartsComparison:
    """The held-out comparison of the candidates.

    Attributes
    ----------
    stages : dict
        Stage -> ``{PART}_rmse`` for each part, and ``best`` (the part with the lowest RMSE).
    score : dict
        Part -> mean over the stages of its RMSE divided by the stage's scale (its training
        target's spread).
    best : str or None
        The part with the lowest score; ``None`` when fewer than :data:`MIN_COMPARED_ROWS`
        rows were held out.
    shipped : str
        The part the model is.
    rows : list of int
        ``[first, last]`` held-out rows compared.
    trained_rows : list of int or None
        ``[0, last]``: the rows the compared correctors were trained on (``train --terms``).
    """

    stages: dict[str, dict[str, float | str]]
    score: dict[str, float]
    best: str | None
    shipped: str
    rows: list[int]
    trained_rows: list[int] | None = None

    @property
    def equally_good(self) -> list[str]:
        """The other parts whose score is within :data:`EQUAL_MARGIN` of the best's (empty when
        there is no best)."""
        if self.best is None:
            return []
        bound = (1.0 + EQUAL_MARGIN) * self.score[self.best]
        return [p for p in PARTS if p != self.best and self.score[p] <= bound]

    def to_dict(self) -> dict:
        """Plain data for ``model.json``, ``metrics.json`` and ``diagnosis.json``."""
        trained = {} if self.trained_rows is None else {"trained_rows": self.trained_rows}
        return {
            **trained,
            "held_out_rows": self.rows,
            "stages": self.stages,
            "score": self.score,
            "best": self.best,
            "equally_good": self.equally_good,
            "equal_margin": EQUAL_MARGIN,
            "shipped": self.shipped,
        }


def passed_through_reason(parts: Mapping) -> str:
    """Why a model's correctors are switched off, in words, from the comparison of its parts
    (:meth:`PartsComparison.to_dict`; empty for a model trained without terms)."""
    if parts.get("shipped") == "terms":
        return "the named terms alone ship"
    return "the corrector lost to the white-box in the free-run check at training"


def compare_parts(
    names: Sequence[str],
    recorded: np.ndarray,
    predictions: Mapping[str, np.ndarray],
    scale: Mapping[str, float],
    first_row: int,
    ship: str = "best",
) -> PartsComparison:
    """Compare the candidates' predictions of the held-out rows.

    Parameters
    ----------
    names : sequence of str
        Stage names, one per column.
    recorded : ndarray, shape (m, Q)
        Recorded stage targets of the held-out rows.
    predictions : mapping of str to ndarray, each shape (m, Q)
        Part (each of :data:`PARTS`) -> its free run over the same rows.
    scale : mapping of str to float
        Stage -> spread of its training target (normalises the RMSE).
    first_row : int
        Recording row of the first held-out row.
    ship : str
        One of :data:`SHIP_CHOICES`. ``"best"`` ships the best part, or ``terms+correctors``
        when too few rows were held out to compare.

    Returns
    -------
    PartsComparison

    Raises
    ------
    ConfigError
        ``ship`` is not one of :data:`SHIP_CHOICES`.
    """
    check_ship(ship)
    stages: dict[str, dict[str, float | str]] = {}
    normalised = {part: [] for part in PARTS}
    for q, name in enumerate(names):
        row: dict[str, float | str] = {}
        for part in PARTS:
            error = rmse(predictions[part][:, q], recorded[:, q])
            row[f"{part}_rmse"] = error
            normalised[part].append(error / (scale[name] or 1.0))
        row["best"] = min(PARTS, key=lambda part: row[f"{part}_rmse"])
        stages[name] = row
    score = {part: float(np.mean(values)) for part, values in normalised.items()}
    m = recorded.shape[0]
    best = min(PARTS, key=score.__getitem__) if m >= MIN_COMPARED_ROWS else None
    shipped = ship if ship != "best" else (best or "terms+correctors")
    return PartsComparison(stages, score, best, shipped, [first_row, first_row + m - 1])


def check_ship(ship: str) -> None:
    """Raise :class:`ConfigError` unless ``ship`` is one of :data:`SHIP_CHOICES`."""
    if ship not in SHIP_CHOICES:
        raise ConfigError(
            f"{ship!r} is not a part to ship; choose one of {', '.join(SHIP_CHOICES)}",
            field="--ship",
        )


@dataclass(frozen=True)
class FittedModel:
    """A trained model with the data it was trained on.

    Attributes
    ----------
    model : GreyBoxModel
    data : ProjectData
        The recording arranged for its chain (``y_wb``: the white-box with its terms).
    split : int
        Last training row; the rows after it are held out.
    calibration_runs : tuple of RecordedRun
        The calibration recordings σ is calibrated on (empty: the halves of the training
        rows).
    """

    model: GreyBoxModel
    data: ProjectData
    split: int
    calibration_runs: tuple[RecordedRun, ...] = ()

    def pass_through(self) -> None:
        """Make the model the white-box with its terms: every stage passed through, and its
        uncertainty calibrated again, on what it was calibrated on, for the chain as it now
        runs
        (:meth:`~fmu_greybox.model.chain.GreyBoxChain.pass_through`; ``training``'s
        ``calibration_check`` follows)."""
        data, rows = self.data, slice(0, self.split + 1)
        chain = self.model.chain
        chain.pass_through(
            data.exo[rows],
            data.y_wb[rows],
            data.outputs[rows],
            calibration_runs=self.calibration_runs,
        )
        self.model.training["calibration_check"] = chain.calibration_check_

    def bench_run(self) -> np.ndarray:
        """The chain's free run over the held-out rows, started at the recording's first row
        (memory from its recorded outputs only), as a bench runs the model; shape
        (n - split - 1, Q)."""
        data = self.data
        mean, _ = self.model.chain.free_run(data.exo, data.y_wb, data.outputs, 0)
        return mean[self.split :]


def compare_fitted(named: FittedModel, plain: FittedModel, ship: str) -> PartsComparison:
    """Compare the three parts of two chains fitted on the same rows (see the module
    docstring).

    Parameters
    ----------
    named : FittedModel
        Correctors trained on the white-box with the named terms.
    plain : FittedModel
        Correctors trained on the plain white-box, on the same rows.
    ship : str
        One of :data:`SHIP_CHOICES`.

    Returns
    -------
    PartsComparison
        Over the rows after ``named.split``, with ``trained_rows`` set.
    """
    rows = slice(named.split + 1, None)
    predictions = {
        "correctors": plain.bench_run(),
        "terms": named.data.y_wb[rows],
        "terms+correctors": named.bench_run(),
    }
    comparison = compare_parts(
        named.model.chain.stage_names,
        named.data.outputs[rows],
        predictions,
        named.model.target_std,
        named.split + 1,
        ship,
    )
    return dataclasses.replace(comparison, trained_rows=[0, named.split])
