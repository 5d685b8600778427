"""Keep the few hypotheses the data support: forward selection through the FMU.

Each round, on top of the hypotheses already kept:

1. **screen** every remaining hypothesis on a short leading window of the training rows: one
   linearised (Gauss-Newton) step from "no effect" on top of the kept hypotheses, with
   sensitivities over a long difference step (two scales), tried at two step lengths, once on
   the low-passed residual and once on the raw one; a hypothesis ranks by the better of the
   two (a delay shows in the fast part the low-pass removes, a stiffness in the slow part the
   ripples of the raw misfit hide) and is refined from its low-passed step;
2. **refine** the best few on a longer leading window (damped Gauss-Newton) with the kept
   magnitudes free (an offset kept first may have absorbed part of a leakage's drift: the
   leakage only pays once the offset may move back), and the kept hypotheses alone refined
   the same way as the reference; then score them on the raw residual over the whole
   recording;
3. **accept** the one with the best information criterion if it is significant three times
   over: the Bayesian information criterion, computed with the effective number of samples
   ``N / tau`` (``tau``: the residual's autocorrelation time), falls by more than
   ``bic_threshold``; the held-out rows, never used in fitting, improve by at least
   ``min_heldout_gain`` (the geometric mean over the observed signals of each signal's
   held-out cost ratio, so that the signal with the largest residual in noise units does not
   outvote the others: a friction force that fixes the pressure and the velocity but leaves the
   position drifting from another effect is still supported); and it removes at least
   ``min_explained`` of the residual energy above the noise floor that is left (so that a
   later hypothesis is not kept for polishing the shape of an earlier one). Each test is
   against the reference (the kept hypotheses, re-tuned when that lowers their cost), and the
   information criterion counts the new hypothesis' magnitudes only;
4. refit every kept hypothesis jointly over the whole training part.

Magnitudes are fitted to the low-passed residual (see :class:`~.calibrate.Calibrator`): it keeps
the fit out of the ripples that lightly damped modes and stick-slip put into the raw misfit.
The decisions (information criterion, held-out gain, energy removed) use the raw residual, and
the kept magnitudes are finished on it (:meth:`~.calibrate.Calibrator.polish`).

Rounds stop when the training residual of every signal is within noise, when no hypothesis
passes, or after ``max_findings`` rounds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fmu_greybox.diagnosis.calibrate import Calibrator, Candidate, autocorrelation_time
from fmu_greybox.diagnosis.hypotheses import Hypothesis
from fmu_greybox.diagnosis.locate import SIGNIFICANT_RATIO
from fmu_greybox.diagnosis.runner import Simulator


@dataclass
class Round:
    """What one selection round saw and decided.

    Attributes
    ----------
    screened : list of (str, float)
        Hypothesis key and its window cost relative to the round's starting cost, best first
        (the top of the list only).
    refined : list of dict
        Per refined hypothesis: ``key``, ``theta``, ``train_ratio``, ``heldout_ratio``,
        ``delta_bic``.
    accepted : str or None
        Key of the hypothesis kept.
    """

    screened: list[tuple[str, float]] = field(default_factory=list)
    refined: list[dict] = field(default_factory=list)
    accepted: str | None = None


class ForwardSelection:
    """Forward selection of hypotheses with held-out and information-criterion tests.

    Parameters
    ----------
    screen_rows : int
        Rows of the screening window (a prefix of the training part).
    refine_rows : int
        Rows of the refinement window.
    refine_top : int
        Hypotheses refined per round.
    max_findings : int
        Largest number of hypotheses kept.
    bic_threshold : float
        Least fall of the information criterion for acceptance.
    min_heldout_gain : float
        Least relative improvement of the held-out mean square for acceptance.
    min_explained : float
        Least share of the training residual energy above the noise floor left that a kept
        hypothesis must remove.
    noise_ratio : float
        Selection stops when every signal's training RMS is within this many noise levels.
    max_iter : int
        Gauss-Newton iterations when refining.
    smoothing : float
        Low-pass time constant [samples] of the residual the magnitudes are fitted to.
    polish_iter : int
        Gauss-Newton iterations on the raw residual that finish the kept magnitudes.

    Attributes
    ----------
    selected_ : Candidate
        The kept hypotheses with their jointly fitted magnitudes and covariance, simulated over
        the whole recording.
    baseline_ : Candidate
        The plain white-box, simulated over the whole recording.
    rounds_ : list of Round
    """

    def __init__(
        self,
        screen_rows: int = 4000,
        refine_rows: int = 10000,
        refine_top: int = 5,
        max_findings: int = 5,
        bic_threshold: float = 10.0,
        min_heldout_gain: float = 0.05,
        min_explained: float = 0.2,
        noise_ratio: float = SIGNIFICANT_RATIO,
        max_iter: int = 5,
        smoothing: float = 20.0,
        polish_iter: int = 2,
    ) -> None:
        self.smoothing = smoothing
        self.polish_iter = polish_iter
        self.screen_rows = screen_rows
        self.refine_rows = refine_rows
        self.min_explained = min_explained
        self.refine_top = refine_top
        self.max_findings = max_findings
        self.bic_threshold = bic_threshold
        self.min_heldout_gain = min_heldout_gain
        self.noise_ratio = noise_ratio
        self.max_iter = max_iter

    def fit(self, simulator: Simulator, hypotheses: list[Hypothesis]) -> ForwardSelection:
        """Select among ``hypotheses``.

        Returns
        -------
        ForwardSelection
            ``self``.
        """
        experiment = simulator.experiment
        n = experiment.n_samples
        full = Calibrator(simulator, n)
        screen_rows = min(self.screen_rows, experiment.train_rows)
        windows = [
            Calibrator(simulator, screen_rows, self.smoothing, 2.0),
            Calibrator(simulator, screen_rows, 0.0, 2.0),
        ]
        longer = Calibrator(simulator, min(self.refine_rows, experiment.train_rows), self.smoothing)
        joint_fit = Calibrator(simulator, n, self.smoothing)
        current = Candidate([], np.zeros(0))
        full.evaluate([current])
        self.baseline_ = current
        self.rounds_: list[Round] = []
        remaining = list(hypotheses)
        while len(current.hypotheses) < self.max_findings and not self._within_noise(full, current):
            round_ = Round()
            self.rounds_.append(round_)
            top = self._screen(windows, current, remaining, round_)
            if not top:
                break
            best = self._refine(longer, full, current, top, round_)
            if best is None:
                break
            round_.accepted = best.hypotheses[-1].key
            remaining = [h for h in remaining if h.key != round_.accepted]
            joint = Candidate(best.hypotheses, best.theta)
            joint_fit.evaluate([joint])
            joint_fit.fit([joint], max_iter=2 if len(joint.hypotheses) == 1 else 3)
            full.evaluate([joint])
            current = joint
        if current.hypotheses:
            full.polish([current], self.polish_iter)
        self.selected_ = current
        return self

    # ------------------------------------------------------------------ steps
    def _within_noise(self, calibrator: Calibrator, c: Candidate) -> bool:
        rows = calibrator.fit_rows
        r = calibrator.experiment.residual(c.simulated[:rows])
        return bool(np.all(np.sqrt(np.mean(r**2, axis=0)) <= self.noise_ratio))

    def _screen(
        self,
        windows: list[Calibrator],
        current: Candidate,
        remaining: list[Hypothesis],
        round_: Round,
    ) -> list[Candidate]:
        """One linearised step of every remaining hypothesis on top of the kept ones, on each
        screening view (the low-passed and the raw residual, in that order); a hypothesis ranks
        by its better view and is refined from its step on the first (the refinement fits the
        low-passed residual: a step on the raw one can land in another of its basins)."""
        best: dict[str, tuple[float, Candidate]] = {}
        for window in windows:
            start = Candidate([], np.zeros(0), fixed=current.terms())
            window.evaluate([start])
            if not math.isfinite(start.cost):
                continue
            candidates = [Candidate([h], h.start(), fixed=current.terms()) for h in remaining]
            for c in candidates:
                c.cost, c.simulated, c.heldout = start.cost, start.simulated, start.heldout
            window.fit(candidates, max_iter=1, tries=1)
            for c in candidates:
                key, ratio = c.hypotheses[-1].key, c.cost / start.cost
                if key not in best:
                    best[key] = (ratio, c)
                elif ratio < best[key][0]:
                    best[key] = (ratio, best[key][1])
        ranked = sorted(best.items(), key=lambda item: item[1][0])
        round_.screened = [(key, ratio) for key, (ratio, _) in ranked[:10]]
        better = [c for _, (ratio, c) in ranked if ratio < 0.99]
        return better[: self.refine_top]

    def _refine(
        self,
        smoothed: Calibrator,
        full: Calibrator,
        current: Candidate,
        top: list[Candidate],
        round_: Round,
    ) -> Candidate | None:
        """Refine the screened candidates (kept magnitudes free) and accept the best that
        passes the three tests against the kept hypotheses refined the same way alone."""
        refined = [_extended(current, c.hypotheses[0], c.theta) for c in top]
        retuned = [_extended(current, None, np.zeros(0))] if current.hypotheses else []
        group = [*refined, *retuned]
        smoothed.evaluate(group)
        smoothed.fit(group, max_iter=self.max_iter)
        full.evaluate(group)
        reference = min([current, *retuned], key=lambda c: c.cost)
        rows = full.fit_rows
        floor = float(rows * len(full.experiment.outputs))
        needed = self.min_explained * max(reference.cost - floor, 0.0)
        base_r = full.experiment.residual(reference.simulated[:rows])
        n_eff = base_r.size / autocorrelation_time(base_r)
        best, best_bic = None, -self.bic_threshold
        for c in refined:
            if not math.isfinite(c.cost):
                continue
            added = c.hypotheses[-1]
            bic = n_eff * math.log(max(c.cost, 1e-300) / reference.cost) + added.n_params * (
                math.log(n_eff)
            )
            held = heldout_ratio(c.heldout, reference.heldout)
            round_.refined.append(
                {
                    "key": added.key,
                    "theta": c.split()[-1].tolist(),
                    "train_ratio": c.cost / reference.cost,
                    "heldout_ratio": held,
                    "delta_bic": bic,
                }
            )
            enough = reference.cost - c.cost >= needed
            if bic < best_bic and held <= 1.0 - self.min_heldout_gain and enough:
                best, best_bic = c, bic
        return best


def _extended(kept: Candidate, hypothesis: Hypothesis | None, theta: np.ndarray) -> Candidate:
    """The kept hypotheses, plus ``hypothesis`` at ``theta`` when given, all free to move."""
    added = [] if hypothesis is None else [hypothesis]
    return Candidate([*kept.hypotheses, *added], np.concatenate([kept.theta, theta]))


def heldout_ratio(new: np.ndarray | None, old: np.ndarray | None) -> float:
    """Geometric mean over the observed signals of the held-out cost ratio ``new / old``.

    Parameters
    ----------
    new, old : ndarray, shape (n_observed,), or None
        Mean squared normalised held-out residual of each signal (``None``: no held-out rows).

    Returns
    -------
    float
        1.0 when there is nothing to compare.
    """
    if new is None or old is None:
        return 1.0
    kept = old > 0
    if not np.any(kept):
        return 1.0
    ratios = np.maximum(new[kept], 1e-300) / old[kept]
    return float(np.exp(np.mean(np.log(ratios))))
