"""Keep the few hypotheses the data support: forward selection through the FMU.

Each round, on top of the hypotheses already kept:

1. **screen** every remaining hypothesis on a leading window of the training rows (at least
   ``screen_rows``, and long enough to hold 30 % of the residual's energy beyond noise: a
   simulation starts at the first row, and the mismatch may show only later): one
   linearised (Gauss-Newton) step from "no effect" on top of the kept hypotheses, with
   sensitivities over a long difference step (two scales), tried at two step lengths, on the
   low-passed residual, the raw one and the spectrum (on the first two only when its linear
   model promises :data:`SCREEN_PROMISE` of the window's cost); a hypothesis ranks by its best
   view (a delay shows in the fast part the low-pass removes, a stiffness in the slow part the
   ripples of the raw misfit hide, a lightly damped mode's frequency in the spectrum, where the
   step is also compared with probes at a few multiples of its scale) and is refined
   from its low-passed step, or from its spectrum step when the spectrum ranked it best. The
   best ``refine_top`` of distinct physics go on;
2. **refine** them on a longer leading window (at least ``refine_rows``, and 60 % of the
   energy beyond noise; damped Gauss-Newton; the spectrum-ranked ones on
   the spectrum first, which brings a mode's frequency into the narrow valley the time-domain
   misfit has around it; a candidate is then probed one scale either way and goes on from a
   probe that fits better, :func:`_escape`, since a screening step can land in a ripple beside
   the valley where no local step helps) with the kept
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
   information criterion counts the new hypothesis' magnitudes only. A candidate that makes any
   observed signal's held-out RMSE worse by more than ``max_harm`` is never accepted. The
   other refined candidates that pass these tests and fit nearly as well
   (:func:`~.alternatives.is_alternative`) are kept as the accepted one's alternatives. Where
   an added term and a mis-set parameter of the white-box name the same physics and fit
   nearly as well, the parameter is accepted: it corrects the model's own physics instead of adding
   structure beside it;
4. refit every kept hypothesis jointly over the whole training part.

After the last round every kept hypothesis is checked once more, with the others at their joint
magnitudes: one without which some observed signal's held-out RMSE is better by more than
``max_harm`` is dropped (``dropped_``).

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

from fmu_greybox.data.noise import SIGNIFICANT_RATIO, significance, structure_left
from fmu_greybox.diagnosis.alternatives import is_alternative, nearly_as_good, physics_of
from fmu_greybox.diagnosis.calibrate import Calibrator, Candidate, HeldOut
from fmu_greybox.diagnosis.hypotheses import Hypothesis, ParameterMismatch
from fmu_greybox.diagnosis.runner import Simulator
from fmu_greybox.model.calibration import autocorrelation_time


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
    alternatives : list of Candidate
        Refined candidates nearly as good as the accepted one, best first.
    screen_rows, refine_rows : int
        Rows of the screening and the refinement windows.
    """

    screened: list[tuple[str, float]] = field(default_factory=list)
    refined: list[dict] = field(default_factory=list)
    accepted: str | None = None
    alternatives: list[Candidate] = field(default_factory=list)
    screen_rows: int = 0
    refine_rows: int = 0


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
    max_harm : float
        Largest relative worsening of any observed signal's held-out RMSE a kept hypothesis
        may cause.

    Attributes
    ----------
    selected_ : Candidate
        The kept hypotheses with their jointly fitted magnitudes and covariance, simulated over
        the whole recording.
    baseline_ : Candidate
        The plain white-box, simulated over the whole recording.
    rounds_ : list of Round
    dropped_ : list of dict
        Hypotheses dropped after the rounds because they worsened a held-out signal: ``key``,
        ``signal``, ``worsening`` (relative RMSE change).
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
        max_harm: float = 0.05,
    ) -> None:
        self.max_harm = max_harm
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
        joint_fit = Calibrator(simulator, n, self.smoothing)
        current = Candidate([], np.zeros(0))
        full.evaluate([current])
        self.baseline_ = current
        self.rounds_: list[Round] = []
        remaining = list(hypotheses)
        while len(current.hypotheses) < self.max_findings and not self._within_noise(full, current):
            round_ = Round()
            self.rounds_.append(round_)
            train = experiment.residual(current.simulated[: experiment.train_rows])
            round_.screen_rows = max(self.screen_rows, informative_rows(train, 0.3))
            round_.refine_rows = max(self.refine_rows, informative_rows(train, 0.6))
            screen_rows = min(round_.screen_rows, experiment.train_rows)
            windows = [
                Calibrator(simulator, screen_rows, self.smoothing, 2.0),
                Calibrator(simulator, screen_rows, 0.0, 2.0),
                Calibrator(simulator, screen_rows, 0.0, 2.0, spectrum=True),
            ]
            refine_rows = min(round_.refine_rows, experiment.train_rows)
            longer = Calibrator(simulator, refine_rows, self.smoothing)
            spectral = Calibrator(simulator, refine_rows, spectrum=True)
            top = self._screen(windows, current, remaining, round_)
            if not top:
                break
            best = self._refine(longer, spectral, full, current, top, round_)
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
        self.dropped_: list[dict] = []
        self.selected_ = self._drop_harmful(full, current)
        alternatives = [c for r in self.rounds_ for c in r.alternatives]
        if alternatives:
            full.covariance(alternatives)
        return self

    # ------------------------------------------------------------------ steps
    def harm(self, new: HeldOut | None, old: HeldOut | None) -> tuple[int, float] | None:
        """The observed signal whose held-out RMS (of the judged residual, :class:`HeldOut`)
        ``new`` worsens most against ``old``, and by how much (relative), when that exceeds
        :attr:`max_harm`; else ``None``."""
        if new is None or old is None:
            return None
        change = new.rms / np.maximum(old.rms, 1e-300) - 1.0
        j = int(np.argmax(change))
        return (j, float(change[j])) if change[j] > self.max_harm else None

    def _drop_harmful(self, full: Calibrator, selected: Candidate) -> Candidate:
        """The kept hypotheses without those that worsen a held-out signal beyond
        :attr:`max_harm` with the others at their joint magnitudes (worst first, one at a
        time)."""
        outputs = full.experiment.outputs
        while selected.hypotheses:
            pairs = list(zip(selected.hypotheses, selected.split(), strict=True))
            without = [
                Candidate([h for h, _ in pairs if h is not left], _joined(pairs, left))
                for left, _ in pairs
            ]
            full.evaluate(without)
            harms = [self.harm(selected.heldout, c.heldout) for c in without]
            worst = max(
                (i for i, h in enumerate(harms) if h is not None),
                key=lambda i: harms[i][1],
                default=None,
            )
            if worst is None:
                return selected
            signal, worsening = harms[worst]
            self.dropped_.append(
                {
                    "key": pairs[worst][0].key,
                    "signal": outputs[signal],
                    "worsening": worsening,
                }
            )
            selected = without[worst]
        return selected

    def _within_noise(self, calibrator: Calibrator, c: Candidate) -> bool:
        rows = calibrator.fit_rows
        experiment = calibrator.experiment
        simulated = c.simulated[:rows]
        ratio, significant = significance(
            experiment.residual(simulated), experiment.bands(simulated)
        )
        return not np.any(significant | (ratio > self.noise_ratio))

    def _screen(
        self,
        windows: list[Calibrator],
        current: Candidate,
        remaining: list[Hypothesis],
        round_: Round,
    ) -> list[tuple[Candidate, bool]]:
        """One linearised step of every remaining hypothesis on top of the kept ones, on each
        screening view (the low-passed residual, the raw one, the spectrum, in that order; on the
        low-passed one the better of the steps from sensitivities taken up and down, since the sign
        of an effect is not known yet and a drift shows there, :meth:`Calibrator.fit`; the
        spectrum's probes try both signs); a hypothesis ranks by its best view. It is refined from
        its step on the low-passed residual (the one the refinement fits: a step on the raw one can
        land in another of its basins), unless the spectrum ranked it best: then from its step
        there, and first on the spectrum. The best few of distinct physics go on (two variants of
        one effect compete for one place, so that a near tie of duplicates does not crowd out other
        physics); a variant with more magnitudes (``KEY+asymmetric``) brings its simpler form along,
        so that the information criterion can choose between them. Variants of a chosen physics that
        the screen cannot tell from it (:func:`_tied`: a viscous force on the motor's speed and a
        mis-set load friction behind a rigid gear) come along too, up to :data:`TIED_VARIANTS` in
        all, outside the count: the refinement decides between them or gives them as alternatives.

        Returns
        -------
        list of (Candidate, bool)
            The candidates to refine, and whether each starts on the spectrum.
        """
        best: dict[str, tuple[float, Candidate, bool]] = {}
        for window in windows:
            start = Candidate([], np.zeros(0), fixed=current.terms())
            window.evaluate([start])
            if not math.isfinite(start.cost):
                continue
            candidates = [Candidate([h], h.start(), fixed=current.terms()) for h in remaining]
            for c in candidates:
                c.cost, c.simulated, c.heldout = start.cost, start.simulated, start.heldout
            spectral = window.spectrum is not None
            # both signs on the low-passed view, where a drift shows and refinement starts
            window.fit(
                candidates,
                max_iter=1,
                tries=1,
                both_sides=window.smoothing > 0,
                min_predicted_gain=0.0 if spectral else SCREEN_PROMISE,
            )
            if spectral:
                _probe(window, candidates)
            for c in candidates:
                key, ratio = c.hypotheses[-1].key, c.cost / start.cost
                if key not in best:
                    best[key] = (ratio, c, spectral)
                elif ratio < best[key][0]:
                    best[key] = (ratio, c if spectral else best[key][1], spectral)
        ranked = sorted(best.items(), key=lambda item: item[1][0])
        round_.screened = [(key, ratio) for key, (ratio, _, _) in ranked[:10]]
        top: list[tuple[Candidate, bool]] = []
        families: dict[str, list[float]] = {}
        for key, (ratio, c, spectral) in ranked:
            if ratio >= 0.99:
                break
            family = physics_of(c.hypotheses[-1])
            chosen = families.get(family)
            if chosen is None and len(families) < self.refine_top:
                families[family] = [ratio]
                picks = [(c, spectral)]
                simpler = best.get(key.split("+")[0])
                if simpler is not None and simpler[1] is not c:
                    picks.append((simpler[1], simpler[2]))
            elif chosen is not None and len(chosen) < TIED_VARIANTS and _tied(ratio, chosen[0]):
                chosen.append(ratio)
                picks = [(c, spectral)]
            else:
                continue
            top.extend(p for p in picks if not any(p[0] is t for t, _ in top))
        return top

    def _refine(
        self,
        smoothed: Calibrator,
        spectral: Calibrator,
        full: Calibrator,
        current: Candidate,
        top: list[tuple[Candidate, bool]],
        round_: Round,
    ) -> Candidate | None:
        """Refine the screened candidates (kept magnitudes free; those the spectrum ranked best
        on the spectrum first) and accept the best that passes the three tests against the kept
        hypotheses refined the same way alone."""
        refined = [_extended(current, c.hypotheses[0], c.theta) for c, _ in top]
        first = [c for c, (_, on_spectrum) in zip(refined, top, strict=True) if on_spectrum]
        if first:
            spectral.evaluate(first)
            spectral.fit(first, max_iter=self.max_iter)
        retuned = [_extended(current, None, np.zeros(0))] if current.hypotheses else []
        group = [*refined, *retuned]
        smoothed.evaluate(group)
        smoothed.fit(group, max_iter=self.max_iter)
        past_ripples(smoothed, refined, self.max_iter)
        full.evaluate(group)
        reference = min([current, *retuned], key=lambda c: c.cost)
        rows = full.fit_rows
        floor = float(rows * len(full.experiment.outputs))
        needed = self.min_explained * max(reference.cost - floor, 0.0)
        base_r = full.experiment.residual(reference.simulated[:rows])
        n_eff = base_r.size / autocorrelation_time(base_r)
        best, best_bic = None, -self.bic_threshold
        scored = []
        passing: list[tuple[Candidate, float]] = []
        outputs = full.experiment.outputs
        for c in refined:
            if not math.isfinite(c.cost):
                continue
            added = c.hypotheses[-1]
            bic = n_eff * math.log(max(c.cost, 1e-300) / reference.cost) + added.n_params * (
                math.log(n_eff)
            )
            held = heldout_ratio(c.heldout, reference.heldout)
            harm = self.harm(c.heldout, reference.heldout)
            entry = {
                "key": added.key,
                "start": "spectrum" if any(c is f for f in first) else "residual",
                "theta": c.split()[-1].tolist(),
                "train_ratio": c.cost / reference.cost,
                "heldout_ratio": held,
                "delta_bic": bic,
            }
            if harm is not None:
                entry["rejected"] = (
                    f"worsens the held-out fit of {outputs[harm[0]]} by {100 * harm[1]:.1f} %"
                )
            round_.refined.append(entry)
            enough = reference.cost - c.cost >= needed
            passes = held <= 1.0 - self.min_heldout_gain and enough and harm is None
            scored.append((c, bic, passes))
            if passes:
                passing.append((c, bic))
            if bic < best_bic and passes:
                best, best_bic = c, bic
        if best is None:
            return None
        best, best_bic = _own_parameter_first(best, best_bic, passing)
        for (c, bic, passed), entry in zip(scored, round_.refined, strict=True):
            margins = {
                "delta_bic": bic - best_bic,
                "heldout_ratio": heldout_ratio(c.heldout, best.heldout),
            }
            if c is not best and passed and is_alternative(best, c, **margins):
                entry["alternative"] = margins
                round_.alternatives.append(c)
        round_.alternatives.sort(key=lambda c: c.cost)
        return best


def _own_parameter_first(
    best: Candidate, best_bic: float, passing: list[tuple[Candidate, float]]
) -> tuple[Candidate, float]:
    """The accepted candidate, or a mis-set parameter of the white-box of the same physics that
    the data cannot tell from it (:func:`~.alternatives.nearly_as_good`):
    it corrects the model's own physics instead of adding structure beside it.

    Parameters
    ----------
    best : Candidate
        The best candidate by the information criterion, ``best_bic`` its criterion.
    passing : list of (Candidate, float)
        The candidates that passed the acceptance tests, with their criteria.

    Returns
    -------
    (Candidate, float)
    """
    if isinstance(best.hypotheses[-1], ParameterMismatch):
        return best, best_bic
    physics = physics_of(best.hypotheses[-1])
    tied = [
        (c, bic)
        for c, bic in passing
        if isinstance(c.hypotheses[-1], ParameterMismatch)
        and physics_of(c.hypotheses[-1]) == physics
        and nearly_as_good(bic - best_bic, heldout_ratio(c.heldout, best.heldout))
    ]
    return min(tied, key=lambda pair: pair[1], default=(best, best_bic))


#: On the time-domain views a screened candidate's step is tried only when its linear model
#: predicts that the window's cost falls by at least this share: a tenth of the 1 % a candidate
#: must explain to go on (``ratio >= 0.99`` ends the screen's ranking). The spectrum's steps are
#: always tried: far from a mode it is flat, and its linear model says least there
#: (``benchmarks/screen_promise.py``).
SCREEN_PROMISE = 1e-3
#: Most variants of one physics refined in a round (the best and those tied with it).
TIED_VARIANTS = 3
#: A variant is tied with its physics' best when it explains at least this share of what the
#: best explains in the screen.
TIE_SHARE = 0.9


def _tied(ratio: float, best: float) -> bool:
    """Whether a screen cost ratio ``ratio`` ties with ``best`` (:data:`TIE_SHARE`)."""
    return 1.0 - ratio >= TIE_SHARE * (1.0 - best)


#: Multiples of its scale at which the spectrum screen probes a hypothesis' first magnitude.
PROBES = (-10.0, -3.0, 3.0, 10.0)


def _probe(window: Calibrator, candidates: list[Candidate]) -> None:
    """Move each candidate to the best of its probes (:data:`PROBES`) where that beats its
    screening step: far from a mode's frequency the spectrum is flat, and no local step from
    "no effect" reaches the valley around it."""
    probes = []
    for c in candidates:
        h = c.hypotheses[-1]
        thetas = []
        for multiple in PROBES:
            theta = h.start()
            theta[0] += multiple * h.scale[0]
            thetas.append(theta)
        probes.append(thetas)
    window.move_to_best(candidates, probes)


#: Times a refined candidate may leave a basin its steps cannot (:func:`_escape`).
ESCAPES = 2


def _escape(calibrator: Calibrator, candidates: list[Candidate]) -> list[Candidate]:
    """Move each refined candidate one scale either way along each magnitude of its new
    hypothesis where that lowers its cost (:meth:`~.calibrate.Calibrator.move_to_best`); the
    candidates moved.

    A parameter that tunes a lightly damped mode (a bulk modulus, a mass) leaves ripples on
    the low-passed misfit too: a screening step can land in a dip beside the valley, where
    every local step costs more and the refinement stops, worse than "no effect" on the raw
    residual. A probe one scale away steps over the ripple; a candidate at its valley's floor
    stays where it is.
    """
    live = [c for c in candidates if math.isfinite(c.cost)]
    probes = []
    for c in live:
        own = c.theta.size - c.hypotheses[-1].n_params
        scale = c.scale
        steps = []
        for k in range(own, c.theta.size):
            for sign in (-1.0, 1.0):
                theta = c.theta.copy()
                theta[k] += sign * scale[k]
                steps.append(theta)
        probes.append(steps)
    return calibrator.move_to_best(live, probes)


def past_ripples(calibrator: Calibrator, candidates: list[Candidate], max_iter: int) -> int:
    """Refined candidates escape a ripple (:func:`_escape`) and are refined again from there,
    at most :data:`ESCAPES` times; the number of escapes made."""
    stuck, escapes = candidates, 0
    while escapes < ESCAPES:
        stuck = _escape(calibrator, stuck)
        if not stuck:
            break
        calibrator.fit(stuck, max_iter=max_iter)
        escapes += 1
    return escapes


def informative_rows(residual: np.ndarray, share: float) -> int:
    """Rows from the start within which ``share`` of a residual's energy beyond noise lies.

    A window that starts at the first row (a simulation starts there) must reach the rows where
    the mismatch shows: an amplifier that saturates only on the large commands of the test's
    second half leaves its first seconds at noise level.

    Parameters
    ----------
    residual : ndarray, shape (n, n_observed)
        Noise-normalised residual (noise alone: unit mean square).
    share : float

    Returns
    -------
    int
        Between 1 and ``n``.
    """
    excess = np.cumsum(np.sum(np.maximum(residual**2 - 1.0, 0.0), axis=1))
    if excess.size == 0 or excess[-1] <= 0:
        return residual.shape[0]
    return int(np.searchsorted(excess, share * excess[-1])) + 1


def _joined(pairs: list[tuple[Hypothesis, np.ndarray]], left: Hypothesis) -> np.ndarray:
    """The magnitudes of every hypothesis of ``pairs`` but ``left``, concatenated."""
    kept = [theta for h, theta in pairs if h is not left]
    return np.concatenate(kept) if kept else np.zeros(0)


def _extended(kept: Candidate, hypothesis: Hypothesis | None, theta: np.ndarray) -> Candidate:
    """The kept hypotheses, plus ``hypothesis`` at ``theta`` when given, all free to move."""
    added = [] if hypothesis is None else [hypothesis]
    return Candidate([*kept.hypotheses, *added], np.concatenate([kept.theta, theta]))


def heldout_ratio(new: HeldOut | None, old: HeldOut | None) -> float:
    """Geometric mean over the observed signals of the held-out structure ratio ``new / old``.

    A signal's structure is its whitened held-out power beyond noise in the frequency bands where
    either fit leaves structure beyond chance (:attr:`~fmu_greybox.data.noise.Bands.structured`);
    both are regularised by the power at the chance threshold of those bands, so that a signal left
    at noise level by both counts 1. Structure concentrated in a band (an offset, a resonance) then
    counts in full, not diluted by the noise of the other bands.

    Parameters
    ----------
    new, old : HeldOut or None
        Fits over the held-out rows (``None``: no held-out rows).

    Returns
    -------
    float
        1.0 when there is nothing to compare.
    """
    if new is None or old is None:
        return 1.0
    excess_new, excess_old, floor = structure_left(new.bands, old.bands)
    ratios = np.where(floor > 0, (excess_new + floor) / np.maximum(excess_old + floor, 1e-300), 1.0)
    return float(np.exp(np.mean(np.log(ratios))))
