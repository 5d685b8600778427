"""Fit hypotheses' magnitudes through the FMU: damped Gauss-Newton on noise-normalised residuals.

The residual of a candidate (a set of hypotheses with magnitudes, on top of terms already
accepted) is ``(recorded - simulated) / sigma`` over the training rows of every observed
signal. Sensitivities come from perturbed simulations (forward differences); every batch of
simulations of every candidate in an iteration runs at once on the :class:`~.runner.Simulator`'s
workers. Steps are Gauss-Newton directions with backtracking (two step lengths tried in
parallel) inside the hypotheses' admissible ranges.

A calibrator fits one **view** of the residual: the time-domain residual (optionally low-passed)
or its **spectrum**: the log power spectral densities of every observed output, simulated
against recorded, per frequency (:class:`SpectrumView`). The spectrum ignores phase, so a
lightly damped mode whose frequency a parameter sets gives a smooth, single valley in it, where
the time-domain misfit of the ringing is flat far from the right value and ripples near it
(once simulated and recorded ringing drift out of phase, no local step helps).

The covariance of the magnitudes is the larger of the Gauss-Newton one, ``s^2 (J^T J)^-1``
inflated by the residual's integrated autocorrelation time (neighbouring samples of a
model-error residual are not independent: the effective number of samples is ``N / tau``), and a
block sandwich estimate that also widens when different stretches of the recording ask for
different magnitudes (see :meth:`Calibrator.covariance`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.fft
from scipy.signal import filtfilt, get_window

from fmu_greybox.data.noise import Bands
from fmu_greybox.diagnosis.hypotheses import Hypothesis
from fmu_greybox.diagnosis.memo import Memo
from fmu_greybox.diagnosis.runner import Experiment, Simulator
from fmu_greybox.model.calibration import autocorrelation_time
from fmu_greybox.model.terms import Term

#: Memory a calibrator keeps the residuals of its latest simulations in (a diagnosis holds
#: several calibrators at once).
RESIDUAL_BYTES = 8 * 2**20


class SpectrumView:
    """The spectrum view of a residual over the first ``rows`` rows of an experiment.

    The residual is, per observed output and Welch frequency bin, ``w (log(S_sim + N) - log(S_rec +
    N))``: ``S`` the power spectral densities (Welch, segments of :data:`SEGMENT` samples, a quarter
    of the rows at most), ``N`` the sensor noise's density (the recording carries it, the simulation
    does not), ``w`` the whitening gain against the drift input noise drives
    (:class:`~fmu_greybox.data.noise.DriftWhitening`): the simulation carries that drift and the
    recording does not, so where it dominates (an integrating output's low frequencies) a bin says
    nothing about the hypotheses and has no weight. Each is scaled by the square root of the number
    of segments averaged, which makes it about unit variance.

    Parameters
    ----------
    experiment : Experiment
    rows : int
    """

    #: Longest Welch segment [samples]: wide bins (4 Hz at 1 kHz), so that a resonance
    #: simulated at another frequency still overlaps the recorded one and the misfit slopes
    #: towards it.
    SEGMENT = 256

    def __init__(self, experiment: Experiment, rows: int) -> None:
        self.segment = max(8, min(self.SEGMENT, rows // 4))
        self.fs = 1.0 / experiment.dt
        self.window = get_window("hann", self.segment)
        freq, recorded = self.density(experiment.recorded[:rows])
        self.white = 2.0 * experiment.dt * experiment.sigma**2
        self.log_recorded = np.log(recorded + self.white)
        scale = math.sqrt(max(1.0, 2.0 * rows / self.segment - 1.0))
        self.weight = np.full(recorded.shape, scale)
        whitening = experiment.whitening
        if whitening is not None:
            for j, ratio in enumerate(whitening.ratio.T):
                self.weight[:, j] /= np.sqrt(1.0 + np.interp(freq, whitening.frequency, ratio))

    def density(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """One-sided power spectral densities of the columns of ``x`` by Welch's method: Hann
        segments of :attr:`segment` samples overlapping by half, each less its mean (what
        :func:`scipy.signal.welch` computes by default, equal to rounding, with every segment
        transformed at once).

        Parameters
        ----------
        x : ndarray, shape (n, k)

        Returns
        -------
        frequency : ndarray, shape (segment // 2 + 1,)
        density : ndarray, shape (segment // 2 + 1, k)
        """
        hop = self.segment - self.segment // 2
        starts = np.arange((x.shape[0] - self.segment) // hop + 1) * hop
        segments = x[starts[:, None] + np.arange(self.segment)[None, :]]
        segments = segments - segments.mean(axis=1, keepdims=True)
        spectra = scipy.fft.rfft(segments * self.window[None, :, None], axis=1)
        power = (spectra.real**2 + spectra.imag**2) / (self.fs * np.sum(self.window**2))
        power[:, 1 : (self.segment + 1) // 2] *= 2.0  # one-sided: all but 0 and Nyquist
        return np.fft.rfftfreq(self.segment, 1.0 / self.fs), power.mean(axis=0)

    def residual(self, simulated: np.ndarray) -> np.ndarray | None:
        """The spectrum residual of a simulation of the rows, flattened (None if not finite)."""
        _, power = self.density(simulated)
        r = (np.log(power + self.white) - self.log_recorded) * self.weight
        return r.ravel() if np.all(np.isfinite(r)) else None


@dataclass
class HeldOut:
    """How a simulation fits the held-out rows.

    Attributes
    ----------
    bands : Bands
        Band powers of the residual (:meth:`~.runner.Experiment.bands`).
    rms : ndarray, shape (n_observed,)
        RMS of each observed signal's judged residual (noise-normalised, whitened against
        input-noise drift: :meth:`~.runner.Experiment.residual`). For a signal without
        input-noise drift it is its RMSE over its noise level; for an integrating one it is not
        swayed by where the drift of its held-out part happens to wander.
    """

    bands: Bands
    rms: np.ndarray


@dataclass
class Candidate:
    """Hypotheses with magnitudes, on top of fixed terms.

    Attributes
    ----------
    hypotheses : list of Hypothesis
        Fitted jointly.
    theta : ndarray, shape (p,)
        Their magnitudes, concatenated.
    fixed : list of Term
        Terms already accepted, applied unchanged.
    cost : float
        Sum of squared normalised residuals over the training rows simulated.
    heldout : HeldOut or None
        Fit over the held-out rows (``None`` unless simulated, or when no row is held out).
    simulated : ndarray or None
        The last simulation at ``theta``.
    cov : ndarray or None, shape (p, p)
        Covariance of ``theta`` (after :meth:`Calibrator.covariance`).
    """

    hypotheses: list[Hypothesis]
    theta: np.ndarray
    fixed: list[Term] = field(default_factory=list)
    cost: float = math.inf
    heldout: HeldOut | None = None
    simulated: np.ndarray | None = None
    cov: np.ndarray | None = None
    _step: float = 1.0
    _done: bool = False

    @property
    def scale(self) -> np.ndarray:
        return np.array([s for h in self.hypotheses for s in h.scale], dtype=np.float64)

    @property
    def lower(self) -> np.ndarray:
        return np.array([s for h in self.hypotheses for s in h.lower], dtype=np.float64)

    @property
    def upper(self) -> np.ndarray:
        return np.array([s for h in self.hypotheses for s in h.upper], dtype=np.float64)

    def split(self, theta: np.ndarray | None = None) -> list[np.ndarray]:
        """``theta`` cut into one array per hypothesis."""
        theta = self.theta if theta is None else theta
        if not self.hypotheses:
            return []
        cuts = np.cumsum([h.n_params for h in self.hypotheses])[:-1]
        return np.split(np.asarray(theta, dtype=np.float64), cuts)

    def terms(self, theta: np.ndarray | None = None) -> list[Term]:
        """Fixed terms plus the hypotheses' terms at ``theta`` (default: the current one)."""
        own = [
            t for h, th in zip(self.hypotheses, self.split(theta), strict=True) for t in h.terms(th)
        ]
        return [*self.fixed, *own]

    def clip(self, theta: np.ndarray) -> np.ndarray:
        return np.clip(theta, self.lower, self.upper)

    @property
    def ci95(self) -> np.ndarray:
        """``(p, 2)`` 95 % intervals from :attr:`cov` (``nan`` when unknown)."""
        if self.cov is None:
            return np.full((self.theta.size, 2), np.nan)
        half = 1.96 * np.sqrt(np.maximum(np.diag(self.cov), 0.0))
        return np.column_stack([self.theta - half, self.theta + half])


class Calibrator:
    """Evaluates and fits candidates over a prefix of the recording.

    Parameters
    ----------
    simulator : Simulator
    rows : int
        Rows simulated (a prefix; the rows beyond the training part score the held-out fit).
    smoothing : float
        Time constant, in samples, of a zero-phase low-pass filter applied to the residual
        before it is scored (0: none). Lightly damped modes make the raw misfit of a parameter
        that tunes them (a stiffness, a mass) a narrow valley with ripples around it: once the
        simulated ringing is out of phase with the recorded one, no local step helps. The
        smoothed misfit keeps the slow, well-behaved part (e.g. the position a compliance
        lets drift, the mean motion of a stick-slip) and has its minimum in the valley.
    difference_step : float
        Finite-difference step, in units of each magnitude's scale. A long step measures the
        trend of the misfit rather than the ripples left on it (what a first, screening step
        from "no effect" needs); a short one the local slope (what the last steps need).
    spectrum : bool
        Fit the spectrum view instead of the time-domain residual (``smoothing`` unused).
    """

    def __init__(
        self,
        simulator: Simulator,
        rows: int,
        smoothing: float = 0.0,
        difference_step: float = 0.5,
        spectrum: bool = False,
    ) -> None:
        self.simulator = simulator
        self.experiment = simulator.experiment
        self.rows = rows
        self.fit_rows = min(rows, self.experiment.train_rows)
        self.smoothing = smoothing
        self.difference_step = difference_step
        self.spectrum = SpectrumView(self.experiment, self.fit_rows) if spectrum else None
        self._residuals: Memo[int, tuple[np.ndarray, np.ndarray | None]] = Memo(
            RESIDUAL_BYTES, lambda kept: 0 if kept[1] is None else kept[1].nbytes
        )

    # ------------------------------------------------------------------ residuals
    def residual(self, simulated: np.ndarray | None) -> np.ndarray | None:
        """Training-row residual vector of a simulation (None if the FMU failed; read-only).

        A simulation's residual is computed once while it is among the latest
        :data:`RESIDUAL_BYTES` kept: a screen's candidates all start from one simulation, and
        a fit takes the sensitivities and the step from the residual it has just scored.
        """
        if simulated is None:
            return None
        kept = self._residuals.get(id(simulated))
        if kept is not None and kept[0] is simulated:
            return kept[1]
        r = self._residual(simulated)
        if r is not None:
            r.setflags(write=False)
        self._residuals.keep(id(simulated), (simulated, r))  # the array kept: its id stays its own
        return r

    def _residual(self, simulated: np.ndarray) -> np.ndarray | None:
        if self.spectrum is not None:
            return self.spectrum.residual(simulated[: self.fit_rows])
        r = self.simulator.training_residual(simulated, self.fit_rows)
        if not np.all(np.isfinite(r)):
            return None
        if self.smoothing > 0:
            a = math.exp(-1.0 / self.smoothing)
            r = filtfilt([1.0 - a], [1.0, -a], r, axis=0)
        return r.ravel()

    def heldout(self, simulated: np.ndarray) -> HeldOut | None:
        """The fit over the held-out rows simulated; ``None`` when none is."""
        rest = simulated[self.fit_rows :]
        if rest.shape[0] < 2:
            return None
        judged = self.experiment.residual(rest, self.fit_rows)
        return HeldOut(
            self.experiment.bands(rest, self.fit_rows), np.sqrt(np.mean(judged**2, axis=0))
        )

    def _run(self, term_sets: Sequence[Sequence[Term]]) -> list:
        """The simulations of ``term_sets`` over :attr:`rows` (their residuals computed by the
        simulation workers where this view is the time-domain one)."""
        return self.simulator.run(term_sets, self.rows, scored=self.spectrum is None)

    def evaluate(self, candidates: Sequence[Candidate]) -> None:
        """Simulate every candidate at its magnitudes and store cost and simulation."""
        sims = self._run([c.terms() for c in candidates])
        for c, sim in zip(candidates, sims, strict=True):
            self._store(c, c.theta, sim)

    def _store(self, c: Candidate, theta: np.ndarray, sim: np.ndarray | None) -> bool:
        r = self.residual(sim)
        if r is None:
            return False
        c.theta = np.array(theta, dtype=np.float64)
        c.cost = float(np.dot(r, r))
        c.simulated = sim
        c.heldout = self.heldout(sim)
        return True

    def move_to_best(
        self, candidates: Sequence[Candidate], probes: Sequence[Sequence[np.ndarray]]
    ) -> list[Candidate]:
        """Simulate each candidate at its probe magnitudes (clipped to its range) and move it to
        the best probe where that lowers its cost: a local step cannot leave a basin, a probe a
        few scales away can.

        Parameters
        ----------
        candidates : sequence of Candidate
            Evaluated by this calibrator.
        probes : sequence of sequence of ndarray
            Per candidate, the magnitudes to try (each shape (p,)).

        Returns
        -------
        list of Candidate
            The candidates moved.
        """
        trials = [
            (c, Candidate(c.hypotheses, c.clip(theta), fixed=c.fixed))
            for c, thetas in zip(candidates, probes, strict=True)
            for theta in thetas
        ]
        self.evaluate([trial for _, trial in trials])
        best: dict[int, Candidate] = {}
        for c, trial in trials:
            if trial.cost < best.get(id(c), c).cost:
                best[id(c)] = trial
        moved = [c for c in candidates if id(c) in best]
        for c in moved:
            self._store(c, best[id(c)].theta, best[id(c)].simulated)
        return moved

    # ------------------------------------------------------------------ sensitivities
    def _steps(self, c: Candidate, backward: bool = False) -> np.ndarray:
        """Signed finite-difference steps, inside the admissible range: up (down with
        ``backward``) unless that leaves the range."""
        scale = c.scale
        h = self.difference_step * scale * np.maximum(1.0, 0.1 * np.abs(c.theta / scale))
        if backward:
            return np.where(c.theta - h >= c.lower, -h, h)
        return np.where(c.theta + h <= c.upper, h, -h)

    def jacobians(
        self, candidates: Sequence[Candidate], backward: bool = False
    ) -> list[np.ndarray | None]:
        """One-sided difference sensitivities ``d r / d theta`` of each candidate (steps up,
        or down with ``backward``; see :meth:`_steps`).

        Returns
        -------
        list of (ndarray, shape (N, p), or None when a perturbed run failed)
        """
        tasks, owners = [], []
        steps = [self._steps(c, backward) for c in candidates]
        for i, (c, h) in enumerate(zip(candidates, steps, strict=True)):
            for k in range(c.theta.size):
                theta = c.theta.copy()
                theta[k] += h[k]
                tasks.append(c.terms(theta))
                owners.append((i, k))
        sims = self._run(tasks)
        base = [self.residual(c.simulated) for c in candidates]
        jac: list[np.ndarray | None] = [
            np.empty((b.size, c.theta.size)) if b is not None else None
            for c, b in zip(candidates, base, strict=True)
        ]
        for (i, k), sim in zip(owners, sims, strict=True):
            r = self.residual(sim)
            if jac[i] is None or r is None:
                jac[i] = None
                continue
            jac[i][:, k] = (r - base[i]) / steps[i][k]
        return jac

    # ------------------------------------------------------------------ fitting
    def fit(
        self,
        candidates: Sequence[Candidate],
        max_iter: int = 6,
        tol: float = 1e-3,
        tries: int = 3,
        both_sides: bool = False,
        min_predicted_gain: float = 0.0,
    ) -> None:
        """Damped Gauss-Newton on every candidate at once, in place.

        Each candidate must have been evaluated (:meth:`evaluate`). An iteration computes the
        sensitivities, then tries the Gauss-Newton step at two lengths; the better one is kept
        if it lowers the cost, otherwise the step length shrinks ninefold and the pair is tried
        again, at most ``tries`` times. A candidate stops when its cost falls by less than
        ``tol`` (relative), no step helps, or after ``max_iter`` iterations.

        With ``both_sides`` the sensitivities are also taken with steps down, and the step
        whose linear model predicts the lower cost is tried. From "no effect" the sign of an
        effect is not known, and a secant taken on the wrong side of a response that saturates
        says little: a command offset makes the simulated ram drift to an end stop, and a step
        that drifts it there sooner barely changes the misfit, while a step the other way does.

        A candidate whose best step's linear model predicts that the cost falls by less than
        ``min_predicted_gain`` (relative) stops without trying it: a screen asks far more of a
        candidate than its step could give, and its trial runs are the screen's largest cost.
        """
        active = [c for c in candidates if math.isfinite(c.cost)]
        for c in active:
            c._done, c._step = False, 1.0
        for _ in range(max_iter):
            active = [c for c in active if not c._done]
            if not active:
                return
            sides = [(active, self.jacobians(active))]
            if both_sides:  # where a bound does not turn the step down into the step up
                two = [c for c in active if np.any(self._steps(c, True) != self._steps(c))]
                sides.append((two, self.jacobians(two, backward=True)))
            found: dict[int, tuple[float, np.ndarray]] = {}
            for side, jacs in sides:
                for c, jac in zip(side, jacs, strict=True):
                    if jac is None:
                        continue
                    step, predicted = self._direction(c, jac)
                    if predicted < found.get(id(c), (math.inf,))[0]:
                        found[id(c)] = (predicted, step)
            directions = []
            for c in active:
                if id(c) in found and not self._unpromising(c, found[id(c)][0], min_predicted_gain):
                    directions.append((c, found[id(c)][1]))
                else:
                    c._done = True
            self._line_search(directions, tol, tries)

    @staticmethod
    def _unpromising(c: Candidate, predicted: float, min_gain: float) -> bool:
        """Whether a step predicted to reach cost ``predicted`` gains less than ``min_gain``
        (relative) on ``c``'s cost (never with ``min_gain`` 0)."""
        return min_gain > 0 and predicted > (1.0 - min_gain) * c.cost

    def _direction(self, c: Candidate, jac: np.ndarray) -> tuple[np.ndarray, float]:
        """The Gauss-Newton step (in magnitude units), lightly regularised, and the cost its
        linear model predicts."""
        r = self.residual(c.simulated)
        scale = c.scale
        js = jac * scale
        a = js.T @ js
        g = js.T @ r
        ridge = 1e-9 * np.trace(a) / max(a.shape[0], 1) + 1e-300
        try:
            step = -np.linalg.solve(a + ridge * np.eye(a.shape[0]), g)
        except np.linalg.LinAlgError:
            step = np.zeros_like(g)
        predicted = r + js @ step
        return step * scale, float(np.dot(predicted, predicted))

    def _line_search(
        self, directions: list[tuple[Candidate, np.ndarray]], tol: float, tries: int
    ) -> None:
        pending = [(c, d) for c, d in directions if np.any(d != 0)]
        for c, d in directions:
            if not np.any(d != 0):
                c._done = True
        for _ in range(tries):
            if not pending:
                return
            tasks, trials = [], []
            for c, d in pending:
                for alpha in (c._step, c._step / 3.0):
                    theta = c.clip(c.theta + alpha * d)
                    tasks.append(c.terms(theta))
                    trials.append((c, theta, alpha))
            sims = self._run(tasks)
            best: dict[int, tuple[float, np.ndarray, float, np.ndarray]] = {}
            for (c, theta, alpha), sim in zip(trials, sims, strict=True):
                r = self.residual(sim)
                if r is None:
                    continue
                cost = float(np.dot(r, r))
                if cost < best.get(id(c), (math.inf,))[0]:
                    best[id(c)] = (cost, theta, alpha, sim)
            retry = []
            for c, d in pending:
                found = best.get(id(c))
                if found is not None and found[0] < c.cost:
                    cost, theta, alpha, sim = found
                    gain = (c.cost - cost) / max(c.cost, 1e-300)
                    self._store(c, theta, sim)
                    c._step = min(1.0, 3.0 * alpha) if alpha == c._step else alpha
                    c._done = gain < tol
                else:
                    c._step /= 9.0
                    if c._step < 1e-3:
                        c._done = True
                    else:
                        retry.append((c, d))
            pending = retry
        for c, _ in pending:
            c._done = True

    def covariance(
        self, candidates: Sequence[Candidate], blocks: int = 20
    ) -> list[np.ndarray | None]:
        """Set each candidate's covariance from sensitivities at its magnitudes.

        Two estimates are formed and the larger (by trace) is kept:

        * Gauss-Newton, ``s^2 (J^T J)^-1`` times the residual's autocorrelation time;
        * a block sandwich ``A^-1 (sum_b g_b g_b^T) A^-1`` over ``blocks`` contiguous blocks of
          the training rows (``g_b``: a block's gradient, ``A = J^T J``): robust to
          autocorrelation and to a hypothesis that fits some stretches better than others,
          which model-structure error produces.

        Returns
        -------
        list of (ndarray or None)
            The sensitivities used (see :meth:`jacobians`).
        """
        jacs = self.jacobians(candidates)
        for c, jac in zip(candidates, jacs, strict=True):
            if jac is None:
                continue
            r = self.residual(c.simulated)
            n, p = jac.shape
            scale = c.scale
            js = jac * scale
            inv = np.linalg.pinv(js.T @ js)
            m = self.fit_rows
            tau = autocorrelation_time(r.reshape(m, -1))
            gauss_newton = float(np.dot(r, r)) / max(n - p, 1) * tau * inv
            width = r.size // m
            cuts = np.linspace(0, m, blocks + 1).round().astype(int) * width
            grads = np.array([js[a:b].T @ r[a:b] for a, b in itertools.pairwise(cuts)])
            meat = grads.T @ grads * blocks / max(blocks - p, 1)
            sandwich = inv @ meat @ inv
            best = sandwich if np.trace(sandwich) > np.trace(gauss_newton) else gauss_newton
            c.cov = best * np.outer(scale, scale)
        return jacs

    def polish(self, candidates: Sequence[Candidate], max_iter: int = 2, seed: int = 0) -> None:
        """Finish magnitudes fitted on a low-passed residual on this calibrator's residual, and
        set their covariance, widened by two systematic terms (added as variances):

        * **score**: both residuals are consistent scores of a correct model; where their
          estimates differ, a structural difference between the hypothesis and the real
          physics weighs differently in the two;
        * **input noise**: what is left of the recorded inputs' sensor noise after their
          smoothing still drives the white-box (errors in variables). The shift of one
          Gauss-Newton step when that error is drawn afresh
          (:meth:`~.runner.Experiment.renoised`) measures it.

        The candidates must have been evaluated by this calibrator.
        """
        before = [c.theta.copy() for c in candidates]
        self.fit(candidates, max_iter=max_iter, tol=1e-4)
        jacs = self.covariance(candidates)
        experiment = self.experiment
        rng = np.random.default_rng(seed)
        noisy = experiment.renoised(rng)
        for c, theta, jac in zip(candidates, before, jacs, strict=True):
            if c.cov is None or jac is None:
                continue
            shift = np.zeros_like(c.theta)
            sim = noisy.simulate(c.terms(), self.rows)
            r_noisy = self.residual(sim)
            if r_noisy is not None:
                js = jac * c.scale
                step = np.linalg.pinv(js) @ (r_noisy - self.residual(c.simulated))
                shift = -step * c.scale
            c.cov = c.cov + np.diag((c.theta - theta) ** 2 + shift**2)
