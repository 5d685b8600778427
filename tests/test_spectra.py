"""Frequency-domain checks: trusted frequencies, bounds, band statistics, and the figure.

Known systems stand in for the recording: a first-order filter (gain and phase known in closed
form), a pure delay (phase wrapping many times over the band) and a filter whose output is
buried in noise above a frequency (where nothing may be trusted).
"""

from __future__ import annotations

import numpy as np
import pytest
from figures import overlapping_tick_labels
from scipy import signal

from fmu_greybox.evidence.plots import frequency_figure
from fmu_greybox.evidence.spectra import MIN_COHERENCE, frequency_response

DT = 1e-3


def first_order(u: np.ndarray, a: float = 0.9) -> np.ndarray:
    """``y[k] = a y[k-1] + (1 - a) u[k-1]``: H(z) = (1 - a) z^-1 / (1 - a z^-1)."""
    return signal.lfilter([0.0, 1.0 - a], [1.0, -a], u)


def exact_first_order(freq: np.ndarray, a: float = 0.9) -> np.ndarray:
    z = np.exp(-2j * np.pi * freq * DT)
    return (1 - a) * z / (1 - a * z)


def test_gain_and_phase_of_a_known_filter_with_units_and_band_statistics() -> None:
    rng = np.random.default_rng(0)
    u = rng.standard_normal(2**15)
    y = first_order(u)
    r = frequency_response(
        u,
        {"recording": y, "grey-box": y, "white-box": 2 * y},
        DT,
        "valve_current",
        "spool_position",
        stage="EHV",
        units=("mA", "m"),
    )
    exact = exact_first_order(r.freq)
    keep = r.trusted
    assert keep.sum() > 0.9 * r.freq.size  # a clean record: (nearly) everything trusted
    np.testing.assert_allclose(
        r.gain_db("recording")[keep], 20 * np.log10(np.abs(exact[keep])), atol=0.2
    )
    np.testing.assert_allclose(
        r.phase_deg("recording")[keep], np.degrees(np.unwrap(np.angle(exact[keep]))), atol=1.0
    )
    assert r.gain_unit == "dB re 1 m/mA"
    doubled = r.band_statistics("white-box", (0.0, 50.0))
    assert doubled.gain_error_db == pytest.approx(20 * np.log10(2), rel=1e-6)
    assert doubled.phase_error_deg == pytest.approx(0.0, abs=1e-9)
    assert doubled.median_coherence > 0.99  # a scaled copy is fully coherent
    assert doubled.bins == int(r.in_band((0.0, 50.0)).sum()) > 0
    same = r.band_statistics("grey-box", (0.0, 50.0))
    assert same.gain_error_db == pytest.approx(0.0, abs=1e-9)


def test_statistics_cover_the_band_of_their_header_only() -> None:
    """An error confined above 100 Hz must not show in a 0-50 Hz statistic, and must in a
    0-300 Hz one."""
    rng = np.random.default_rng(1)
    u = rng.standard_normal(2**15)
    y = first_order(u, 0.5)
    high = signal.lfilter(*signal.butter(4, 150, "highpass", fs=1 / DT), y)
    r = frequency_response(u, {"recording": y, "grey-box": y + 0.5 * high}, DT)
    assert r.band_statistics("grey-box", (0.0, 50.0)).gain_error_db < 0.05
    assert r.band_statistics("grey-box", (0.0, 300.0)).gain_error_db > 0.5


def test_frequencies_where_the_recording_is_noise_are_masked() -> None:
    """Above 100 Hz the recorded output is drowned in noise: its coherence with the input
    falls below the threshold, and gain, phase and statistics leave those frequencies out."""
    rng = np.random.default_rng(2)
    u = rng.standard_normal(2**15)
    y = signal.lfilter(*signal.butter(6, 80, fs=1 / DT), u)
    noisy = y + 0.3 * rng.standard_normal(u.size)
    r = frequency_response(u, {"recording": noisy, "grey-box": y}, DT)
    high = r.freq > 200
    assert not r.trusted[high].any()
    assert np.all(r.coherence["recording"][~r.trusted & (r.freq > 0)] < MIN_COHERENCE)
    assert np.isnan(r.gain_db("grey-box")[high]).all()
    assert np.isnan(r.phase_deg("grey-box")[high]).all()
    assert r.band_statistics("grey-box", (250.0, 500.0)).bins == 0
    assert np.isnan(r.band_statistics("grey-box", (250.0, 500.0)).gain_error_db)


def test_phase_is_unwrapped_across_trusted_frequencies_only() -> None:
    """A delay of 20 samples turns the phase by 7200° at 1 kHz: unwrapped, the phase is the
    straight line -360 f τ over the trusted frequencies, with no jump of 360°."""
    rng = np.random.default_rng(3)
    u = rng.standard_normal(2**15)
    y = np.concatenate([np.zeros(20), u[:-20]])
    r = frequency_response(u, {"recording": y, "grey-box": y}, DT)
    keep = r.trusted
    phase = r.phase_deg("recording")
    np.testing.assert_allclose(phase[keep], -360 * r.freq[keep] * 20 * DT, atol=2.0)
    assert np.all(np.isnan(phase[~keep]))


def test_the_recordings_bounds_hold_the_true_response() -> None:
    """With output noise, the recording's 95 % gain bounds contain the exact gain at about
    95 % of the trusted frequencies (at least 85 % here)."""
    rng = np.random.default_rng(4)
    u = rng.standard_normal(2**14)
    y = first_order(u, 0.7)
    noisy = y + 0.05 * rng.standard_normal(u.size)
    r = frequency_response(u, {"recording": noisy, "grey-box": y}, DT)
    keep = r.trusted & (r.freq < 400)
    lower, upper = r.gain_bounds_db()
    exact = 20 * np.log10(np.abs(exact_first_order(r.freq, 0.7)))
    inside = (exact >= lower) & (exact <= upper)
    assert inside[keep].mean() >= 0.85
    assert np.all(upper[keep] > r.gain_db("recording")[keep])


def test_the_table_band_statistic_is_the_one_plotted() -> None:
    rng = np.random.default_rng(5)
    u = rng.standard_normal(2**14)
    y = first_order(u, 0.8)
    model = first_order(u, 0.75) + 0.02 * rng.standard_normal(u.size)
    r = frequency_response(
        u, {"recording": y, "grey-box": model, "white-box": 1.5 * y}, DT, stage="RAM"
    )
    band = (0.0, 50.0)
    fig = frequency_figure([r], [band])
    coherence_axes = fig.axes[2]
    for source in ("grey-box", "white-box"):
        (segments,) = [
            c for c in coherence_axes.collections if c.get_gid() == f"band median {source}"
        ]
        ((start, end),) = [segment for segment in segments.get_segments()]
        expected = r.band_statistics(source, band)
        assert start[1] == end[1] == pytest.approx(expected.median_coherence, rel=1e-12)
        trusted = r.freq[r.in_band(band)]
        assert (start[0], end[0]) == (trusted.min(), trusted.max())
    assert fig.axes[0].get_title(loc="left").startswith("RAM: ")


@pytest.mark.parametrize(("rows", "passband"), [(8000, (2.0, 60.0)), (2**15, (0.5, 300.0))])
def test_frequency_tick_labels_stand_clear_of_one_another(
    rows: int, passband: tuple[float, float]
) -> None:
    """An 8 s recording excited from 2 to 60 Hz (the demo's RAM) spans under two decades:
    matplotlib labels every minor tick there (``2×10^0 3×10^0 ...``, one unreadable string).
    There as over a wide span, every panel has at least two frequency labels and no two labels
    of one axis overlap once rendered."""
    rng = np.random.default_rng(6)
    u = rng.standard_normal(rows)
    y = signal.lfilter(*signal.butter(4, passband, "bandpass", fs=1 / DT), u)
    noisy = y + np.std(y) * rng.standard_normal(u.size)
    r = frequency_response(
        u, {"recording": noisy, "white-box": 1.3 * y, "grey-box": y}, DT, stage="RAM"
    )
    fig = frequency_figure([r], [(0.0, 50.0)])
    assert overlapping_tick_labels(fig) == []
    for ax in fig.axes:
        labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
        assert len(labels) >= 2, labels
