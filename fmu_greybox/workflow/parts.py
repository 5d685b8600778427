"""Never worse than its parts: on each stage, the white-box alone, with the named terms, with
correctors, or with both, whichever held-out rows support.

A model with named terms (from a diagnosis) is assembled stage by stage from four parts: the
plain white-box (``white-box``), the white-box with the named terms and no corrector
(``terms``), the paper's correctors on the plain white-box (``correctors``), and correctors
trained on top of the named terms (``terms+correctors``). ``diagnose`` free-runs the last three
over the rows it holds out and compares them stage by stage.

``train --terms`` compares them forward in time on a longer stretch: correctors trained on the
first half of the training rows, every part free-run from the recording's first row as a bench
runs it (the chain's memory from the recorded outputs of that row only) and scored on every
later row. The last few percent of a recording rarely leave the regimes its training rows
cover; half a recording more often does, and that is where correctors, which cannot
extrapolate, fall behind named physics.

Each stage then ships the first part, in the order of
:data:`~fmu_greybox.project.config.STAGE_PARTS`, that the best one does not beat clearly
(:func:`choose_stage_part`): the white-box, the terms, the terms with correctors, the
correctors alone (fewer additions first, and the named physics, which extrapolates, before data,
which does not). Beating clearly takes two things: an RMS error lower by more than
:data:`EQUAL_MARGIN` over the held-out rows, and a lower one in most of the :data:`BLOCKS`
consecutive blocks they are cut into, so that one stretch of the recording (a manoeuvre the
correctors happen to know) does not decide for all. Where a corrector takes part in a comparison,
``train`` judges the error as the diagnosis does (:class:`~fmu_greybox.data.noise.ResidualJudge`):
in sensor-noise units and whitened against the drift that the inputs' noise drives through the
white-box. That drift is one realisation of noise, which the next recording does not repeat: a
corrector that learns where it wandered on the training recording wins on that recording's later
rows, by raw RMSE, and loses on the next recording. The white-box and the named terms, a few
magnitudes that cannot learn a drift, are compared on the RMSE. A stage that ships no named terms
takes the plain white-box (the terms' ``stages_off``); a stage that ships no corrector passes it
through. A stage's ``ship`` setting, or ``train --ship`` for every stage, names the part instead.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from fmu_greybox.errors import ConfigError
from fmu_greybox.project.config import BEST, STAGE_PARTS
from fmu_greybox.workflow.metrics import rmse

if TYPE_CHECKING:
    from fmu_greybox.model.store import GreyBoxModel
    from fmu_greybox.project.data import ProjectData

#: The candidates of the diagnosis' comparison and of ``train --ship``, in the order reported.
PARTS = ("correctors", "terms", "terms+correctors")
#: What ``train --ship`` accepts: the best part of each stage, or one part on every stage.
SHIP_CHOICES = (BEST, *PARTS)
#: Fewest held-out rows a comparison is made on; with fewer the data cannot decide.
MIN_COMPARED_ROWS = 50
#: A part whose RMSE is within this share of the best part's is equally good: the held-out rows
#: cannot tell them apart (a held-out mean square within about 10 %, the margin the diagnosis
#: uses for competing explanations).
EQUAL_MARGIN = 0.05
#: Consecutive blocks the held-out rows are cut into; a part beats another clearly only when it
#: also wins in more than half of them.
BLOCKS = 4
#: The parts of a comparison (:data:`PARTS`) in plain words.
PART_WORDS = {
    "white-box": "white-box alone",
    "correctors": "correctors alone",
    "terms": "named terms alone",
    "terms+correctors": "named terms + correctors",
}
#: How each comparison of the parts is labelled wherever it is printed: the diagnosis' short
#: check, and the training's, which decides what ships.
DIAGNOSIS_PARTS = "Diagnosis' quick check of the parts (its held-out rows; training decides)"
TRAINING_PARTS = "Training's comparison of the parts (decides what ships)"


def has_terms(part: str) -> bool:
    """Whether a part (:data:`STAGE_PARTS`) carries the named terms."""
    return part in ("terms", "terms+correctors")


def has_corrector(part: str) -> bool:
    """Whether a part (:data:`STAGE_PARTS`) carries a corrector."""
    return part in ("correctors", "terms+correctors")


@dataclass(frozen=True)
class PartsComparison:
    """The held-out comparison of the candidates.

    Attributes
    ----------
    stages : dict
        Stage -> ``{PART}_rmse`` for each part compared, ``blocks`` (part -> RMSE in each of
        the :data:`BLOCKS` blocks of the held-out rows), with a judge (:func:`compare_parts`)
        ``judged`` and ``judged_blocks`` (the same of the judged residual, in noise units),
        ``best`` (the part with the lowest RMSE) and ``shipped`` (the part chosen for the
        stage, :func:`choose_stage_part`).
    score : dict
        Part -> mean over the stages of its RMSE divided by the stage's scale (its training
        target's spread).
    best : str or None
        The part with the lowest score; ``None`` when fewer than :data:`MIN_COMPARED_ROWS`
        rows were held out.
    shipped : dict of str to str
        Stage -> the part the model is on that stage.
    rows : list of int
        ``[first, last]`` held-out rows compared.
    trained_rows : list of int or None
        ``[0, last]``: the rows the compared correctors were trained on (``train --terms``).
    """

    stages: dict[str, dict]
    score: dict[str, float]
    best: str | None
    shipped: dict[str, str]
    rows: list[int]
    trained_rows: list[int] | None = None

    @property
    def equally_good(self) -> list[str]:
        """The other parts whose score is within :data:`EQUAL_MARGIN` of the best's (empty when
        there is no best)."""
        if self.best is None:
            return []
        bound = (1.0 + EQUAL_MARGIN) * self.score[self.best]
        return [p for p in self.score if p != self.best and self.score[p] <= bound]

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
            "blocks": BLOCKS,
            "shipped": self.shipped,
            "stage_order": list(self.stages),
        }


def shipped_parts(parts: Mapping) -> dict[str, str]:
    """Stage -> the part shipped there, from a comparison's plain data
    (:meth:`PartsComparison.to_dict`; ``model.json`` of earlier versions holds one part for
    every stage; empty for a model trained without terms)."""
    shipped = parts.get("shipped")
    order = parts.get("stage_order") or list(parts.get("stages", {}))  # JSON sorts the keys
    if isinstance(shipped, str):
        return dict.fromkeys(order, shipped)
    shipped = shipped or {}
    return {stage: shipped[stage] for stage in [*order, *shipped] if stage in shipped}


def passed_through_reason(parts: Mapping, stage: str | None = None) -> str:
    """Why a model's correctors (or ``stage``'s) are switched off, in words, from the comparison
    of its parts (:meth:`PartsComparison.to_dict`; empty for a model trained without terms)."""
    shipped = shipped_parts(parts)
    chosen = [shipped.get(stage)] if stage is not None else list(shipped.values())
    if chosen and all(part is not None and not has_corrector(part) for part in chosen):
        return "the held-out comparison of the parts chose no corrector"
    return "the corrector lost to the white-box in the free-run check at training"


def passed_through_text(parts: Mapping, passed: Sequence[str]) -> str:
    """The stages whose correctors are switched off, each with why
    (:func:`passed_through_reason`), e.g. ``"EHV (the held-out comparison of the parts chose
    no corrector), RAM (the corrector lost to ...)"``."""
    by_reason: dict[str, list[str]] = {}
    for stage in passed:
        by_reason.setdefault(passed_through_reason(parts, stage), []).append(stage)
    return "; ".join(f"{', '.join(stages)} ({reason})" for reason, stages in by_reason.items())


def parts_text(parts: Mapping[str, Any]) -> str:
    """A comparison of the parts (:meth:`~fmu_greybox.workflow.parts.PartsComparison.to_dict`)
    in plain words: each part's error score, the best, the equally good and what shipped."""
    score = parts["score"]  # in the order of STAGE_PARTS (a model.json sorts its keys)
    order = dict.fromkeys(p for p in (*STAGE_PARTS, *score) if p in score)
    scores = ", ".join(f"{PART_WORDS.get(part, part)} {score[part]:.3g}" for part in order)
    best = parts.get("best")
    text = f"error score (nRMSE, lower is better): {scores}; "
    text += "too few rows to tell" if best is None else f"best: {PART_WORDS.get(best, best)}"
    equal = parts.get("equally_good") or []
    if equal:
        text += f", as good within {100 * parts['equal_margin']:.0f} %: " + " and ".join(
            PART_WORDS.get(p, p) for p in equal
        )
    shipped = parts.get("shipped")
    if isinstance(shipped, str):  # a model.json of an earlier version: one part everywhere
        text += f"; shipped: {PART_WORDS.get(shipped, shipped)}"
    elif shipped:
        text += "; shipped: " + ", ".join(
            f"{stage} {PART_WORDS.get(part, part)}" for stage, part in shipped_parts(parts).items()
        )
    return text


def block_rmse(predicted: np.ndarray, recorded: np.ndarray, blocks: int = BLOCKS) -> list[float]:
    """RMSE of ``predicted`` in each of ``blocks`` consecutive blocks of rows.

    Parameters
    ----------
    predicted, recorded : ndarray, shape (m,)
    blocks : int

    Returns
    -------
    list of float
        ``blocks`` values (fewer when there are fewer rows).
    """
    edges = np.linspace(0, recorded.size, min(blocks, recorded.size) + 1).astype(int)
    return [rmse(predicted[a:b], recorded[a:b]) for a, b in itertools.pairwise(edges)]


def beats_clearly(
    better: str, worse: str, total: Mapping[str, float], blocks: Mapping[str, Sequence[float]]
) -> bool:
    """Whether part ``better`` beats ``worse`` by more than :data:`EQUAL_MARGIN` over all the
    held-out rows and in more than half of the blocks."""
    if not total[better] < (1.0 - EQUAL_MARGIN) * total[worse]:
        return False
    wins = sum(b < w for b, w in zip(blocks[better], blocks[worse], strict=True))
    return wins > len(blocks[better]) / 2


def choose_stage_part(
    total: Mapping[str, float],
    blocks: Mapping[str, Sequence[float]],
    judged: tuple[Mapping[str, float], Mapping[str, Sequence[float]]] | None = None,
) -> str:
    """The part a stage ships: the first of :data:`STAGE_PARTS` compared that the best part
    (lowest RMSE) does not beat clearly (:func:`beats_clearly`).

    With ``judged``, the first that no other part beats clearly, each pair compared on the
    judged residual when a corrector takes part in it, and on the RMSE when not (the white-box
    against the named terms). A corrector can learn one recording's drift, which the next
    recording does not repeat, and is judged against it; a few named magnitudes cannot, and
    the raw error, drift and all, says whether they hold.

    Parameters
    ----------
    total : mapping of str to float
        Part -> RMSE over the held-out rows (the parts compared).
    blocks : mapping of str to sequence of float
        Part -> RMSE in each block.
    judged : (mapping, mapping), optional
        The same two of the judged residual (:func:`compare_parts`'s ``judge``).

    Returns
    -------
    str
    """
    compared = [p for p in STAGE_PARTS if p in total]
    if judged is None:
        best = min(compared, key=total.__getitem__)
        return next(p for p in compared if p == best or not beats_clearly(best, p, total, blocks))

    def beats(better: str, worse: str) -> bool:
        on = judged if has_corrector(better) or has_corrector(worse) else (total, blocks)
        return beats_clearly(better, worse, *on)

    unbeaten = [p for p in compared if not any(beats(q, p) for q in compared if q != p)]
    return unbeaten[0] if unbeaten else min(compared, key=total.__getitem__)


def compare_parts(
    names: Sequence[str],
    recorded: np.ndarray,
    predictions: Mapping[str, np.ndarray],
    scale: Mapping[str, float],
    first_row: int,
    ship: str = BEST,
    stage_ship: Mapping[str, str] | None = None,
    judge: Callable[[np.ndarray], np.ndarray] | None = None,
) -> PartsComparison:
    """Compare the candidates' predictions of the held-out rows, stage by stage.

    Parameters
    ----------
    names : sequence of str
        Stage names, one per column.
    recorded : ndarray, shape (m, Q)
        Recorded stage targets of the held-out rows.
    predictions : mapping of str to ndarray, each shape (m, Q)
        Part (of :data:`STAGE_PARTS`; at least each of :data:`PARTS`) -> its free run over the
        same rows.
    scale : mapping of str to float
        Stage -> spread of its training target (normalises the RMSE).
    first_row : int
        Recording row of the first held-out row.
    ship : str
        One of :data:`SHIP_CHOICES`: a part shipped on every stage, or ``"best"``: on each
        stage the part ``stage_ship`` names, else the one :func:`choose_stage_part` chooses, or
        ``terms+correctors`` when too few rows were held out to compare.
    stage_ship : mapping of str to str, optional
        Stage -> its ``ship`` setting (:attr:`~fmu_greybox.project.config.StageConfig.ship`).
    judge : callable, optional
        Residuals (recorded minus predicted, shape (m, Q)) -> the residuals a comparison with
        a corrector is made on, same shape (:class:`~fmu_greybox.data.noise.ResidualJudge`: in
        noise units, whitened against input-noise drift; :func:`choose_stage_part`). Without
        it, the RMSE decides.

    Returns
    -------
    PartsComparison

    Raises
    ------
    ConfigError
        ``ship`` is not one of :data:`SHIP_CHOICES`.
    """
    check_ship(ship)
    compared = [p for p in STAGE_PARTS if p in predictions]
    m = recorded.shape[0]
    decided = m >= MIN_COMPARED_ROWS
    stages: dict[str, dict] = {}
    normalised: dict[str, list[float]] = {part: [] for part in compared}
    judged = {p: judge(recorded - predictions[p]) for p in compared} if judge else None
    for q, name in enumerate(names):
        total = {p: rmse(predictions[p][:, q], recorded[:, q]) for p in compared}
        blocks = {p: block_rmse(predictions[p][:, q], recorded[:, q]) for p in compared}
        for part in compared:
            normalised[part].append(total[part] / (scale[name] or 1.0))
        row: dict[str, Any] = {f"{part}_rmse": total[part] for part in compared}
        row["blocks"] = blocks
        evidence = None
        if judged is not None:  # a corrector is judged on the judged residual
            zero = np.zeros(m)
            row["judged"] = {p: rmse(judged[p][:, q], zero) for p in compared}
            row["judged_blocks"] = {p: block_rmse(judged[p][:, q], zero) for p in compared}
            evidence = (row["judged"], row["judged_blocks"])
        chosen = ship if ship != BEST else (stage_ship or {}).get(name, BEST)
        if chosen == BEST:
            chosen = choose_stage_part(total, blocks, evidence) if decided else "terms+correctors"
        stages[name] = {
            **row,
            "best": min(compared, key=total.__getitem__),
            "shipped": chosen,
        }
    score = {part: float(np.mean(values)) for part, values in normalised.items()}
    best = min(compared, key=score.__getitem__) if decided else None
    shipped = {name: row["shipped"] for name, row in stages.items()}
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
    """

    model: GreyBoxModel
    data: ProjectData
    split: int

    def bench_run(self) -> np.ndarray:
        """The chain's free run over the held-out rows, started at the recording's first row
        (memory from its recorded outputs only), as a bench runs the model; shape
        (n - split - 1, Q)."""
        data = self.data
        mean, _ = self.model.chain.free_run(data.exo, data.y_wb, data.outputs, 0)
        return mean[self.split :]


def compare_fitted(
    named: FittedModel,
    plain: FittedModel,
    ship: str,
    judge: Callable[[np.ndarray], np.ndarray] | None = None,
) -> PartsComparison:
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
    judge : callable, optional
        As :func:`compare_parts`.

    Returns
    -------
    PartsComparison
        Over the rows after ``named.split``, with ``trained_rows`` set.
    """
    rows = slice(named.split + 1, None)
    predictions = {
        "white-box": plain.data.y_wb[rows],
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
        {stage.name: stage.ship for stage in named.model.config.stages},
        judge,
    )
    return dataclasses.replace(comparison, trained_rows=[0, named.split])
