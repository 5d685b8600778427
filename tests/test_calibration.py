"""Calibrated uncertainty: the estimator of ``a V + b``, coverage, and a chain whose noise is known.

The chain case is one where the right σ is known: the first stage's recorded output is its
white-box plus white sensor noise of a stated level (nothing to learn: σ must be that level),
the others add smooth maps of the inputs that the correctors learn (σ must be the spread left,
noise and what the corrector misses, and never below the noise); ±1.96σ must cover about 95 %
of rows the chain never saw, in training or in calibration.
"""

from __future__ import annotations

import json
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from scipy.signal import lfilter

from fmu_greybox.evidence.plots import (
    OUTSIDE_STYLE,
    calibration_figure,
    trace_figure,
    zoom_range,
)
from fmu_greybox.model.calibration import (
    UNCALIBRATED,
    Z95,
    autocorrelation_time,
    calibration_rows,
    calibration_spread,
    conformal_quantile,
    coverage,
    coverage_interval,
    error_independent_rows,
    fit_calibration,
    left_out_shares,
    pooled_coverage,
)
from fmu_greybox.model.chain import GreyBoxChain, RecordedRun
from fmu_greybox.project.config import parse_config

REFERENCE = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"


def test_coverage_counts_the_samples_inside_the_band() -> None:
    residual = np.array([0.0, 0.5, -1.0, 1.5, -2.5])
    std = np.ones(5)
    assert coverage(residual, std, 1.0) == pytest.approx(3 / 5)  # the edge counts as inside
    assert coverage(residual, std, Z95) == pytest.approx(4 / 5)
    assert coverage(residual, 2 * std, Z95) == 1.0
    assert np.isnan(coverage(np.zeros(0), np.zeros(0), 1.0))


def test_conformal_quantile_is_the_rank_ceil_m_plus_one_times_level() -> None:
    scores = np.arange(1.0, 101.0)[::-1]  # 1..100, any order
    assert conformal_quantile(scores, 0.95) == 96.0  # ceil(101 * 0.95) = 96
    assert conformal_quantile(scores[-10:], 0.95) == 10.0  # beyond m: the largest


def test_heteroscedastic_gaussian_residuals_give_back_a_and_b() -> None:
    """r ~ N(0, 2 V + 0.5): the estimate recovers both numbers and covers new draws."""
    rng = np.random.default_rng(0)
    latent = rng.uniform(0.0, 4.0, 20000)
    residual = rng.standard_normal(latent.size) * np.sqrt(2.0 * latent + 0.5)
    found = fit_calibration(residual, latent)
    assert found.latent_scale == pytest.approx(2.0, rel=0.05)
    assert found.residual_variance == pytest.approx(0.5, rel=0.1)
    fresh = rng.uniform(0.0, 4.0, 20000)
    new = rng.standard_normal(fresh.size) * np.sqrt(2.0 * fresh + 0.5)
    std = np.sqrt(found.variance(fresh))
    assert coverage(new, std, Z95) == pytest.approx(0.95, abs=0.01)
    assert coverage(new, std, 1.0) == pytest.approx(0.683, abs=0.015)


def test_a_corrector_switched_off_reports_the_residual_level_alone() -> None:
    """V = 0 (or negligible): b is the residual variance, a stays at its prior's centre."""
    rng = np.random.default_rng(1)
    noise = 3.0 * rng.standard_normal(20000)
    for latent in (np.zeros(noise.size), np.full(noise.size, 1e-20)):
        found = fit_calibration(noise, latent)
        assert np.sqrt(found.residual_variance) == pytest.approx(3.0, rel=0.03)
        assert found.latent_scale == pytest.approx(1.0, rel=0.05)


def test_a_slow_wave_is_covered_at_95_percent_not_at_100() -> None:
    """A drift-like residual: matching its variance would put every sample inside ±1.96σ;
    the quantile step puts 95 % of the calibration rows there."""
    wave = np.sin(np.arange(6000) / 300.0)
    found = fit_calibration(wave, np.zeros(wave.size))
    std = np.sqrt(found.variance(np.zeros(wave.size)))
    assert coverage(wave, std, Z95) == pytest.approx(0.95, abs=1e-3)
    assert coverage(wave, np.full(wave.size, wave.std()), Z95) == 1.0


def test_a_left_out_free_run_shows_what_one_recording_can_hold() -> None:
    """``left_out_shares``: each run scored with σ calibrated on the others alone. White
    errors of one size give about 95 % each; a run whose error is three times the others'
    holds far less, and they more (σ calibrated with it)."""
    rng = np.random.default_rng(11)
    runs = [rng.standard_normal(4000) for _ in range(6)]
    latent = [np.zeros(4000)] * 6
    shares = left_out_shares(runs, latent)
    assert len(shares) == 6 and all(0.93 <= s <= 0.97 for s in shares), shares
    runs[2] = 3.0 * runs[2]
    shares = left_out_shares(runs, latent)
    alone = fit_calibration(np.concatenate(runs[:2] + runs[3:]), np.zeros(20000))
    assert shares[2] == coverage(runs[2], np.sqrt(alone.variance(latent[2])), Z95)
    assert shares[2] < 0.6 and min(shares[:2] + shares[3:]) > 0.97, shares
    assert left_out_shares(runs[:1], latent[:1]) == []  # nothing to leave out


def test_without_a_residual_nothing_is_calibrated() -> None:
    assert fit_calibration(np.zeros(50), np.ones(50)) == UNCALIBRATED
    assert fit_calibration(np.array([np.nan]), np.array([1.0])) == UNCALIBRATED


NOISE = (2e-3, 5e-3, 1e-2)  # sensor noise of each stage's recorded output


def noisy_signals(n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Inputs (n, 3), white-box (n, 3) and recorded outputs (n, 3): the white-box (exact for
    the first stage, plus smooth maps of the inputs for the others) plus white noise of the
    levels :data:`NOISE`."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * 1e-3
    exo = np.column_stack(
        [
            np.sin(2 * np.pi * f * t + p)
            for f, p in zip((3.0, 0.7, 1.9), (0.3, 1.0, 2.0), strict=True)
        ]
    )
    wb = np.column_stack([np.sin(2 * np.pi * 2.3 * t), np.cos(2 * np.pi * 1.1 * t), np.sin(5 * t)])
    truth = wb + np.column_stack([np.zeros(n), 0.1 * exo[:, 1], -0.1 * exo[:, 2] ** 2])
    return exo, wb, truth + rng.standard_normal(truth.shape) * np.array(NOISE)


def small_chain(**gp: int) -> GreyBoxChain:
    """The reference chain made small: 30 inducing points, 30 iterations, one lag, residual
    targets fed the recorded outputs (other ``[gp]`` settings from ``gp``)."""
    raw = tomllib.loads(REFERENCE.read_text())
    raw["gp"].update(inducing=30, max_iter=30, target="residual", feeds="recorded", **gp)
    for stage in raw["stages"]:
        stage.update(lags=1, differences=0)
    return GreyBoxChain(parse_config(raw, REFERENCE))


def test_a_chain_reports_the_known_noise_and_covers_95_percent_of_unseen_rows() -> None:
    chain = small_chain()
    exo, wb, out = noisy_signals(6000, seed=4)
    chain.fit(exo[:3000], wb[:3000], out[:3000])
    assert set(chain.calibration_check_) == {"EHV", "RAM", "ITFV"}
    for check in chain.calibration_check_.values():  # white noise: each row counts
        assert 0.7 * check["rows"] <= check["independent_rows"] <= check["rows"], check
    # rows 3000.. were seen by nothing: not by the correctors, not by the calibration
    run = chain.free_run_variances(exo, wb, out, 2999)
    residual = out[3000:] - run.mean
    std = np.sqrt(run.var)
    assert np.median(std[:, 0]) == pytest.approx(NOISE[0], rel=0.1), chain.calibration_[0]
    for q, noise in enumerate(NOISE):
        spread = np.sqrt(np.mean(residual[:, q] ** 2))
        assert noise * 0.95 <= np.median(std[:, q]) == pytest.approx(spread, rel=0.15)
        assert 0.92 <= coverage(residual[:, q], std[:, q], Z95) <= 0.98
        assert 0.62 <= coverage(residual[:, q], std[:, q], 1.0) <= 0.74
        # the propagated variance alone claims far more certainty than the data allow
        assert np.median(np.sqrt(run.latent_var[:, q])) < 0.5 * noise


def test_the_halves_hold_half_the_rows_the_correctors_that_ship_hold(monkeypatch) -> None:
    """On a recording longer than ``max_train_samples`` rows, a calibration half is trained on
    half of what the shipped correctors hold, as on a short recording, not on as much."""
    import fmu_greybox.model.chain as chain_module

    thin, held = chain_module._thin, []

    def counted(X: np.ndarray, t: np.ndarray, limit: int) -> tuple[np.ndarray, np.ndarray]:
        kept = thin(X, t, limit)
        held.append(kept[1].size)
        return kept

    monkeypatch.setattr(chain_module, "_thin", counted)
    exo, wb, out = noisy_signals(3000, seed=4)
    small_chain(max_train_samples=1000).fit(exo, wb, out)
    assert sorted(held) == [500] * 6 + [1000] * 3  # three stages, then two halves of them
    held.clear()
    small_chain(max_train_samples=3000).fit(exo, wb, out)  # every row counts, in halves too
    lost = 3000 - max(held)  # the rows before a fit's first full history
    assert sorted(held) == [1500 - lost] * 6 + [3000 - lost] * 3


def test_calibration_recordings_are_free_run_whole_by_the_chain_that_ships() -> None:
    """``calibration_runs``: σ comes from the shipped chain's own free run over each
    recording, from its first rows, so the calibration holds exactly the conformal share of
    those rows (nothing else calibrated it) and, on recordings of their kind, about 95 %."""
    chain = small_chain()
    exo, wb, out = noisy_signals(3000, seed=4)
    runs = [RecordedRun(*noisy_signals(n, seed)) for n, seed in ((1500, 5), (1200, 6))]
    chain.fit(exo, wb, out, calibration_runs=runs)
    h = chain.history
    residual = np.concatenate(
        [
            r.outputs[h:] - chain.free_run_variances(r.exo, r.y_wb, r.outputs, h - 1).mean
            for r in runs
        ]
    )
    std = np.concatenate(
        [np.sqrt(chain.free_run_variances(r.exo, r.y_wb, r.outputs, h - 1).var) for r in runs]
    )
    m = residual.shape[0]
    assert m == 1500 + 1200 - 2 * h
    for q, name in enumerate(chain.stage_names):
        check = chain.calibration_check_[name]
        assert (check["source"], check["free_runs"], check["rows"]) == ("recordings", 2, m)
        assert check["rmse"] == pytest.approx(np.sqrt(np.mean(residual[:, q] ** 2)), rel=1e-12)
        conformal = math.ceil((m + 1) * 0.95) / m  # the rank the quantile takes (± rounding)
        assert coverage(residual[:, q], std[:, q], Z95) == pytest.approx(conformal, abs=1.5 / m)
    unseen = RecordedRun(*noisy_signals(6000, seed=7))
    run = chain.free_run_variances(unseen.exo, unseen.y_wb, unseen.outputs, h - 1)
    for q in range(3):
        share = coverage(unseen.outputs[h:, q] - run.mean[:, q], np.sqrt(run.var[:, q]), Z95)
        assert 0.92 <= share <= 0.98, (q, share)
    # without them, the halves of the training rows, two free runs by half-trained chains
    chain.fit(exo, wb, out)
    assert {c["source"] for c in chain.calibration_check_.values()} == {"halves"}
    assert chain.calibration_check_["EHV"]["rows"] == 3000 - h


def test_a_free_run_says_where_the_correctors_leave_their_domain() -> None:
    """``FreeRun.in_domain`` (and with it ``validate``'s ``rows_out_of_domain``) is the exported
    FMU's ``out_of_domain`` rule: a regime seen in training (one input at three times its usual
    amplitude, in the first half of the training rows only) is inside; the same input at twelve
    times, beyond every training row, is outside on those rows and nowhere else."""
    chain = small_chain()
    exo, wb, out = noisy_signals(6000, seed=4)
    regime = np.zeros(6000, dtype=bool)
    regime[300:800] = regime[3300:3800] = True  # in the first half and in the unseen rows
    exo[regime, 1] *= 3.0
    out[:, 1] = wb[:, 1] + 0.1 * exo[:, 1] + np.random.default_rng(9).normal(0, NOISE[1], 6000)
    chain.fit(exo[:3000], wb[:3000], out[:3000])
    assert chain.free_run_variances(exo, wb, out, 2999).in_domain.all()
    far = exo.copy()
    far[3300:3800, 1] *= 4.0  # twelve times the usual amplitude: beyond every training row
    outside = np.flatnonzero(~chain.free_run_variances(far, wb, out, 2999).in_domain)
    assert 250 <= outside.size and 300 <= outside.min() and outside.max() <= 802  # row 3000 + i


def test_the_residual_panels_shade_the_rows_outside_the_domain_and_only_those() -> None:
    time = np.arange(1000) * 1e-3
    rng = np.random.default_rng(3)
    recorded, mean = rng.standard_normal((1000, 2)), np.zeros((1000, 2))
    std, names, units = np.ones((1000, 2)), ["A", "B"], ["m", "Pa"]
    outside = (time >= 0.4) & (time < 0.6)

    def shaded_spans(fig) -> list[tuple[float, float]]:
        grey = [c for c in fig.axes[0].collections if c.get_alpha() == OUTSIDE_STYLE["alpha"]]
        return [
            (p.vertices[:, 0].min(), p.vertices[:, 0].max()) for c in grey for p in c.get_paths()
        ]

    fig = trace_figure(time, recorded, mean, mean, std, names, units, outside=outside)
    assert [(round(a, 3), round(b, 3)) for a, b in shaded_spans(fig)] == [(0.4, 0.599)]
    texts = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "correctors outside their domain" in texts
    assert "grey-box ±1.96σ" in texts
    plain = trace_figure(time, recorded, mean, mean, std, names, units, model_label="white-box")
    assert shaded_spans(plain) == []
    # a model without a corrector is drawn under its own name, never "grey-box"
    named = [t.get_text() for t in plain.legends[0].get_texts()]
    titles = " ".join(ax.get_title(loc="left") for ax in plain.axes)
    assert "white-box ±1.96σ" in named and "grey-box" not in " ".join(named) + titles
    assert "correctors outside their domain" not in [
        t.get_text() for t in plain.legends[0].get_texts()
    ]


def test_a_zoom_holds_a_nearby_white_box_and_says_when_it_cuts_a_far_one() -> None:
    low, high, cut = zoom_range(0.0, 1.0, np.array([-1.5, 2.0]))
    assert low < -1.5 and high > 2.0 and cut == ""
    low, high, cut = zoom_range(0.0, 1.0, np.array([0.5, 40.0]))
    assert high < 40.0 and "off scale" in cut and "40" in cut


def test_a_cut_white_box_is_told_in_digits_that_tell_its_ends_apart() -> None:
    """The demo's RAM zoom said 'off scale here (0.0245 to 0.0245)': two equal numbers."""
    _, _, cut = zoom_range(0.02215, 0.0223, np.array([0.024512, 0.024538]))
    assert cut == "white-box off scale above: 0.02451 to 0.02454"
    _, _, cut = zoom_range(0.02215, 0.0223, np.full(5, 0.0245))
    assert cut == "white-box off scale above: constant at 0.0245"
    _, _, cut = zoom_range(0.0, 1.0, np.array([-60.0, -50.0]))
    assert cut == "white-box off scale below: -60 to -50"


def test_the_zoom_draws_its_three_curves_in_styles_that_differ() -> None:
    """Where recording, white-box and grey-box coincide (the demo's ITFV zoom) each still shows:
    no two share line style, marker and width."""
    time = np.arange(1000) * 1e-3
    recorded = np.sin(2 * np.pi * time)[:, None]
    fig = trace_figure(time, recorded, recorded, recorded, np.full((1000, 1), 0.01), ["A"], ["m"])
    lines = fig.axes[1].get_lines()
    styles = {(line.get_linestyle(), line.get_marker(), line.get_linewidth()) for line in lines}
    assert len(lines) == 3 and len(styles) == 3


def test_the_calibration_plot_draws_sigma_before_calibration_only_where_it_shows() -> None:
    """σ before calibration a thousand times too small holds nothing at any level: a dashed
    line on the axis says nothing, so that stage is named in words with the most it held; one
    twice too small is drawn."""
    rng = np.random.default_rng(7)
    recorded, mean = rng.standard_normal((4000, 2)), np.zeros((4000, 2))
    std = np.ones((4000, 2))
    latent = np.column_stack([np.full(4000, 1e-3), np.full(4000, 0.5)])
    fig = calibration_figure(recorded, mean, std, latent, ["RAM", "EHV"])
    labels = [line.get_label() for line in fig.axes[0].get_lines()]
    assert "EHV, before" in labels and "RAM, before" not in labels
    (note,) = [t for t in fig.axes[0].texts if t.get_gid() == "flat before calibration"]
    text = note.get_text()  # at most 2.8σ·1e-3 of unit Gaussian errors: about 0.2 %
    assert re.search(r"RAM \(at most 0\.[12]\d? %\)", text) and "EHV" not in text, text


def ar1(rng: np.random.Generator, rows: int, phi: float) -> np.ndarray:
    """A stationary AR(1) sequence of unit variance (autocorrelation time (1 + phi)/(1 - phi))."""
    e = rng.standard_normal(rows + 2000) * np.sqrt(1.0 - phi**2)
    return lfilter([1.0], [1.0, -phi], e)[2000:]


@pytest.mark.parametrize(("phi", "widest"), [(0.0, 0.035), (0.9, 0.25)])
def test_the_coverage_interval_holds_the_share_of_a_longer_recording(
    phi: float, widest: float
) -> None:
    """On 1 300-row windows of errors whose σ is known (the true share inside ±1.96σ is
    0.95), the 95 % interval must hold 0.95 in at least 95 % of 200 windows, and not be wider
    than it needs: white errors are worth their rows, correlated ones far fewer."""
    rng = np.random.default_rng(5)
    held, widths, worth = 0, [], []
    for _ in range(200):
        residual = ar1(rng, 1300, phi)
        estimate = coverage_interval(residual, np.ones(1300), Z95)
        assert estimate.share == coverage(residual, np.ones(1300), Z95)
        held += estimate.low <= 0.95 <= estimate.high
        widths.append(estimate.high - estimate.low)
        worth.append(estimate.independent_rows)
    assert held >= 190
    assert np.median(widths) <= widest
    # the error's size is less correlated than the error (for Gaussian errors no function of
    # it is more), so the rows are worth at least m / tau of the signed error, and fewer than m
    # when they are correlated
    signed = 1300 * (1.0 - phi) / (1.0 + phi)
    assert 0.9 * signed <= np.median(worth) <= (1300 if phi == 0 else 400)


@pytest.mark.parametrize("phi", [0.0, 0.99, 0.999])
def test_the_calibration_spread_holds_where_its_band_holds_on_recordings_of_its_kind(
    phi: float,
) -> None:
    """A band calibrated (``fit_calibration``) on 19 000 rows (the suite's calibrations) of
    unit-variance AR(1) errors holds ``erf(1.96 σ / √2)`` of an endless recording of the same
    kind. The range
    ``calibration_spread`` gives for the calibration's independent rows must hold that share
    in at least 92 % of 150 calibrations, and narrow with the rows: white errors vouch
    for 0.947-0.953, a drift worth a couple of dozen rows for little more than 0.82-1."""
    rng = np.random.default_rng(17)
    held, lows = 0, []
    for _ in range(150):
        residual = ar1(rng, 19000, phi)
        sigma = math.sqrt(fit_calibration(residual, np.zeros(19000)).residual_variance)
        share = math.erf(Z95 * sigma / math.sqrt(2.0))
        rows = error_independent_rows(residual)
        assert rows == pytest.approx(19000 / autocorrelation_time(residual))
        low, high = calibration_spread(rows)
        held += low <= share <= high
        lows.append(low)
    assert held >= 138, held
    lowest, highest = {0.0: (0.94, 0.95), 0.99: (0.88, 0.93), 0.999: (0.6, 0.88)}[phi]
    assert lowest <= np.median(lows) <= highest


def manoeuvre_errors(rng: np.random.Generator, rows: int) -> np.ndarray:
    """White errors whose size switches between 0.5 and 2 (equally likely) every 1 000-3 000
    rows: a valve's error that follows the manoeuvre, with a sign that changes every row."""
    size = np.empty(rows)
    start = 0
    while start < rows:
        stop = start + int(rng.uniform(1000, 3000))
        size[start:stop] = rng.choice((0.5, 2.0))
        start = stop
    return size * rng.standard_normal(rows)


def test_the_calibration_counts_the_memory_of_its_errors_size_too() -> None:
    """On errors that look white but whose size follows the manoeuvre, the error's own count
    (``error_independent_rows``) takes 19 000 rows for 19 000 independent ones, and the range
    it gives holds the calibrated band's share on an endless recording of that kind in few of
    150 calibrations. ``calibration_rows``, the fewer of that count and the size's, must hold
    it in at least 92 %, like the AR(1) errors' count above."""
    rng = np.random.default_rng(23)
    held = {"error": 0, "calibration": 0}
    for _ in range(150):
        residual = manoeuvre_errors(rng, 19000)
        sigma = math.sqrt(fit_calibration(residual, np.zeros(19000)).residual_variance)
        # half the time at each size, on an endless recording
        share = sum(0.5 * math.erf(Z95 * sigma / size / math.sqrt(2.0)) for size in (0.5, 2.0))
        counts = {
            "error": error_independent_rows(residual),
            "calibration": calibration_rows(residual, np.full(19000, sigma)),
        }
        assert counts["calibration"] <= counts["error"]
        for name, rows in counts.items():
            low, high = calibration_spread(rows)
            held[name] += low <= share <= high
    assert held["calibration"] >= 138, held
    assert held["error"] <= 75, held


def test_the_calibration_spread_is_the_conformal_beta_law() -> None:
    """For ``n`` exchangeable rows the share a split-conformal band holds is
    ``Beta(ceil((n + 1) 0.95), n + 1 - that)``: checked against 4 000 calibrations on white
    errors of 40 rows; no rows give no range."""
    rng = np.random.default_rng(3)
    shares = []
    for _ in range(4000):
        quantile = conformal_quantile(np.abs(rng.standard_normal(40)), 0.95)
        shares.append(math.erf(quantile / math.sqrt(2.0)))
    low, high = calibration_spread(40)
    inside = np.mean((np.array(shares) >= low) & (np.array(shares) <= high))
    assert inside == pytest.approx(0.95, abs=0.012)
    assert all(math.isnan(x) for x in calibration_spread(0.5))


def test_pooled_coverage_decides_what_no_single_drifting_recording_can() -> None:
    """Forty slowly drifting recordings (AR(1), φ = 0.99, 1 300 rows each): the pooled
    interval of a calibrated band holds 0.95 and is far narrower than a single one; that of
    a band 25 % too wide lies wholly above 0.95, though most single intervals still reach it.
    Pooling white rows gives what the concatenated rows give."""
    rng = np.random.default_rng(11)
    windows = [ar1(rng, 1300, 0.99) for _ in range(40)]
    calibrated = [coverage_interval(w, np.ones(1300), Z95) for w in windows]
    wide = [coverage_interval(w, np.full(1300, 1.25), Z95) for w in windows]
    pooled, pooled_wide = pooled_coverage(calibrated), pooled_coverage(wide)
    assert pooled.low <= 0.95 <= pooled.high
    assert pooled.high - pooled.low < 0.3 * np.median([e.high - e.low for e in calibrated])
    assert pooled.independent_rows == pytest.approx(sum(e.independent_rows for e in calibrated))
    assert pooled_wide.low > 0.95
    assert np.mean([e.low <= 0.95 for e in wide]) > 0.5
    white = [rng.standard_normal(700), rng.standard_normal(600)]
    parts = [coverage_interval(w, np.ones(w.size), Z95, w.size) for w in white]
    whole = coverage_interval(np.concatenate(white), np.ones(1300), Z95, 1300)
    assert pooled_coverage(parts) == pytest.approx(whole)
    nothing = pooled_coverage([coverage_interval(np.array([]), np.array([]), Z95)])
    assert nothing.independent_rows == 0 and nothing.share != nothing.share


def test_the_coverage_interval_of_a_band_that_holds_every_row() -> None:
    """All rows inside says little when they are few independent ones, much when many."""
    rng = np.random.default_rng(8)
    slow = coverage_interval(ar1(rng, 1300, 0.99), np.full(1300, 10.0), Z95)
    fast = coverage_interval(rng.standard_normal(1300), np.full(1300, 10.0), Z95)
    assert slow.share == fast.share == 1.0 and slow.high == fast.high == 1.0
    assert slow.low < 0.9 < fast.low
    zero = coverage_interval(np.array([0.0, 1.0, -1.0]), np.zeros(3), Z95)  # σ = 0: outside
    assert zero.share == pytest.approx(1 / 3) and np.isfinite(zero.independent_rows)


def _suite_case(label: str, seed: int, ram: tuple[float, float]) -> dict:
    """A case as ``concealed_effects.py --json`` prints it, with a RAM share and its rows (the
    share's own interval is not pooled: any will do)."""
    share, rows = ram
    stage = {"coverage68": share, "coverage95": share, "independent_rows": rows}
    stage |= {"coverage95_low": 0.0, "coverage95_high": 1.0}
    return {
        "case": label,
        "suite": "actuator",
        "seed": seed,
        "control": False,
        "origin_correct": True,
        "effect_correct": True,
        "consistent": True,
        "findings": ["offset"],
        "harmful_kept": 0,
        "improvement": -0.9,
        "seconds": 1.0,
        "coverage": {"RAM": stage},
    }


def test_the_suite_pools_its_parts_logs(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """``concealed_effects.py --summarise`` reads the cases of a suite run in parts (one part
    stopped before its last line, one case run twice: the later counts) and pools each stage's
    shares by their independent rows."""
    from concealed_effects import logged_cases, main, summary

    first, again, other = (
        _suite_case("offset=0.3", 104, (0.8, 10.0)),
        _suite_case("offset=0.3", 104, (1.0, 6.0)),
        _suite_case("deadband=2e-05", 106, (0.9, 30.0)),
    )
    stopped, resumed = tmp_path / "part1.log", tmp_path / "part2.log"
    stopped.write_text(f"true effect ...\n{json.dumps(first)}\n", encoding="utf-8")
    resumed.write_text(
        f"{json.dumps(again)}\n{json.dumps(other)}\n{json.dumps({'cases': [again, other]})}\n",
        encoding="utf-8",
    )
    cases = logged_cases([str(stopped), str(resumed)])
    assert [c["case"] for c in cases] == ["offset=0.3", "deadband=2e-05"]
    pooled = summary(cases)["coverage95_pooled"]["RAM"]
    assert pooled["independent_rows"] == pytest.approx(36.0)
    assert pooled["coverage95"] == pytest.approx((1.0 * 6 + 0.9 * 30) / 36)
    assert pooled["recordings"] == 2
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(
            "sys.argv", ["concealed_effects.py", "--summarise", str(stopped), str(resumed)]
        )
        main()
    assert "RAM pooled over 2 cases: 91.7 %" in capsys.readouterr().out
    # a decided narrow band is counted, and so is whether its recording's errors were larger
    # than those its σ was calibrated on by enough to account for it (3 times: about 50 % of
    # Gaussian errors expected inside; 1.1 times: 92.5 %, which does not)
    narrow = [_suite_case("saturation@valve_current=4", 124 + i, (0.6, 20.0)) for i in range(3)]
    for case, scored in zip(narrow, (3e-4, 1.1e-4, None), strict=True):
        case["coverage"]["RAM"] |= {"coverage95_low": 0.35, "coverage95_high": 0.87}
        if scored is not None:  # the third is of a run that did not store it
            case["coverage"]["RAM"] |= {"gb_rmse": scored, "calibration_rmse": 1e-4}
    counted = summary([*cases, *narrow])["coverage95_narrow"]
    assert (counted["decided"], counted["told"], counted["shifted"]) == (3, 2, 1)
    first = counted["stages"][0]
    assert (first["case"], first["stage"]) == ("saturation@valve_current=4", "RAM")
    assert first["k"] == pytest.approx(3.0)
    assert first["predicted"] == pytest.approx(math.erf(Z95 / 3 / math.sqrt(2)))
    assert "k" not in counted["stages"][2]
    # how far each share lies from the one its k predicts, over the stages that give k
    by_size = summary([*cases, *narrow])["coverage95_by_size"]
    gaps = [abs(0.6 - math.erf(Z95 / k / math.sqrt(2))) for k in (3.0, 1.1)]
    assert by_size["stages"] == 2 and by_size["max_gap"] == pytest.approx(max(gaps))
    # k = 1.1 predicts a share in the target (92.5 %), k = 3 one outside; neither lies in it
    assert (by_size["predicted_in"], by_size["in_of_predicted_in"]) == (1, 0)
    assert (by_size["predicted_out"], by_size["in_of_predicted_out"]) == (1, 0)
    in_target = {**narrow[1], "coverage": {"RAM": {**narrow[1]["coverage"]["RAM"]}}}
    in_target["coverage"]["RAM"]["coverage95"] = 0.93
    by_size = summary([*cases, narrow[0], in_target])["coverage95_by_size"]
    assert (by_size["predicted_in"], by_size["in_of_predicted_in"]) == (1, 1)
    # stages that say what their calibration rows were worth: 5 000 rows vouch for the target
    # (94.4-95.6 % on recordings like them), 20 do not (82-99.9 %); one of each lies in it
    narrow[0]["coverage"]["RAM"]["calibration_independent_rows"] = 20.0
    in_target["coverage"]["RAM"]["calibration_independent_rows"] = 5000.0
    by_worth = summary([*cases, narrow[0], in_target])["coverage95_by_worth"]
    expected = {"vouched": 1, "in_of_vouched": 1, "unvouched": 1, "in_of_unvouched": 0}
    assert {k: by_worth[k] for k in expected} == expected
    # the Beta law of 20 rows: 0.99^20 - 0.9^20 of such bands hold a share in the target
    assert by_worth["expected_of_unvouched"] == pytest.approx(0.99**20 - 0.9**20)
    assert by_worth["expected_of_vouched"] == pytest.approx(1.0)
    log = tmp_path / "worth.log"
    assert (
        "in 0.90..0.99: 1 of the 1 stages whose calibration rows vouch for it on recordings "
        "like them (1.0 expected from their rows), 0 of the 1 whose rows are too few (0.7 "
        "expected)"
    ) in _summarised(log, [narrow[0], in_target], capsys)
    # stages that say what their calibration's free runs held (each with σ from the others):
    # the narrow one's 60 % lies in 30-100 %, the other's 93 % not in 95-99 %
    narrow[0]["coverage"]["RAM"] |= {"calibration_share_low": 0.3, "calibration_share_high": 1.0}
    in_target["coverage"]["RAM"] |= {"calibration_share_low": 0.95, "calibration_share_high": 0.99}
    by_runs = summary([*cases, narrow[0], in_target])["coverage95_by_free_runs"]
    assert by_runs == {"stages": 2, "in_range": 1, "misses": 1, "misses_in_range": 1}
    assert (
        "in the range of shares the calibration's free runs held (each with σ from the others): "
        "1 of 2 stages, 1 of the 1 outside 0.90..0.99"
    ) in _summarised(log, [narrow[0], in_target], capsys)


def _summarised(log: Path, cases: list[dict], capsys: pytest.CaptureFixture) -> str:
    """What ``concealed_effects.py --summarise`` prints for these cases, written to ``log``."""
    from concealed_effects import main

    log.write_text("".join(json.dumps(c) + "\n" for c in cases), "utf-8")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("sys.argv", ["concealed_effects.py", "--summarise", str(log)])
        main()
    return capsys.readouterr().out
