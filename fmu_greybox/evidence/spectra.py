"""Frequency-domain validation: frequency responses and coherences of recording and models.

The paper leaves frequency-domain validation open; a test-bench engineer reads a model's fit as
much from its Bode plot as from its time traces. For each stage output ``y`` and an excitation
``u`` (the stage's acceptance input: by default the first input of the first stage) this
module estimates, with Welch
averaging (Hann windows, 50 % overlap, segments of ``n / 8`` rounded down to a power of two):

* the frequency response ``H1(f) = P_uy(f) / P_uu(f)`` of the recording, the white-box and the
  grey-box, in dB re 1 (output unit)/(input unit) and degrees;
* the magnitude-squared coherence ``C_uy(f)`` of each, which says where the estimate is
  trustworthy (near 1: a linear response dominates; low: noise or non-linearity);
* the coherence between each model's output and the recorded output, ``C_ym(f)``: where it is
  near 1, the model reproduces the recording's content in that band.

What is trusted: frequencies where the input carries power (``P_uu`` at least
:data:`EXCITATION_FLOOR` of its peak; the others are dropped) and where the recording's own
coherence ``C_uy`` reaches :data:`MIN_COHERENCE`, the guideline of frequency-domain system
identification (Tischler and Remple, *Aircraft and Rotorcraft System Identification*) below which
an estimate's random error is too large to compare models with. Elsewhere nothing is drawn or
counted, and phase is unwrapped only across trusted frequencies. The recording's estimate
carries a 95 % bound from its normalised random error
``ε = √(1 − C) / (|√C| √(2 n_d))`` (Bendat and Piersol; ``n_d``: the Welch segments, counted as
independent): gain within ``20 log10(1 ± 1.96 ε)`` dB, phase within ``± 1.96 ε`` rad.

Every statistic over a band (:meth:`FrequencyResponse.band_statistics`) is taken over the
trusted frequencies inside that band, from the same curves the figure draws.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy import signal

#: Input power below this fraction of its peak: band not excited, dropped.
EXCITATION_FLOOR = 1e-6
#: The recording's input-output coherence below which its frequency response is not trusted.
MIN_COHERENCE = 0.6
#: Half-width of the 95 % bounds, in standard errors.
Z95 = 1.959963984540054


@dataclass(frozen=True)
class BandStatistics:
    """A model's frequency-domain errors over the trusted frequencies of a band.

    Attributes
    ----------
    band : tuple of float
        ``(low, high)`` [Hz].
    bins : int
        Trusted frequencies in the band (0: nothing to compare, every statistic NaN).
    gain_error_db : float
        RMS of ``20 log10 |H_model / H_recording|`` [dB].
    phase_error_deg : float
        RMS of the phase of ``H_model / H_recording`` (within ±180°) [deg].
    median_coherence : float
        Median coherence of the model's output with the recorded output.
    recording_bound_db : float
        Median upper half-width of the recording's 95 % gain bound there [dB]: gain errors
        below it are within the estimate's own uncertainty.
    """

    band: tuple[float, float]
    bins: int
    gain_error_db: float
    phase_error_deg: float
    median_coherence: float
    recording_bound_db: float


@dataclass(frozen=True)
class FrequencyResponse:
    """Frequency responses of several sources of one output to one input.

    Attributes
    ----------
    stage : str
        The stage whose output this is (for titles).
    input_name, output_name : str
    input_unit, output_unit : str
    freq : ndarray, shape (F,)
        Frequencies [Hz] where the input is excited.
    response : dict[str, ndarray of complex, shape (F,)]
        Source (``recording``, ``white-box``, ``grey-box``) -> ``H1`` estimate.
    coherence : dict[str, ndarray, shape (F,)]
        Source -> magnitude-squared coherence between input and output.
    match : dict[str, ndarray, shape (F,)]
        Model source -> coherence between its output and the recorded output.
    segments : int
        Welch segments averaged.
    """

    stage: str
    input_name: str
    output_name: str
    input_unit: str
    output_unit: str
    freq: np.ndarray
    response: dict[str, np.ndarray]
    coherence: dict[str, np.ndarray]
    match: dict[str, np.ndarray]
    segments: int

    @property
    def gain_unit(self) -> str:
        """The gain's unit, e.g. ``dB re 1 m/mA``."""
        return f"dB re 1 {self.output_unit or '1'}/{self.input_unit or '1'}"

    @property
    def trusted(self) -> np.ndarray:
        """Frequencies (above zero) where the recording's coherence reaches
        :data:`MIN_COHERENCE`, shape (F,) of bool."""
        return (self.freq > 0) & (self.coherence["recording"] >= MIN_COHERENCE)

    def in_band(self, band: tuple[float, float]) -> np.ndarray:
        """Trusted frequencies inside ``band`` [Hz], shape (F,) of bool."""
        return self.trusted & (self.freq >= band[0]) & (self.freq <= band[1])

    def gain_db(self, source: str) -> np.ndarray:
        """``20 log10 |H|`` of ``source``, NaN where untrusted, shape (F,) [:attr:`gain_unit`]."""
        gain = 20 * np.log10(np.abs(self.response[source]) + 1e-300)
        return np.where(self.trusted, gain, np.nan)

    def phase_deg(self, source: str) -> np.ndarray:
        """Phase of ``source`` unwrapped across the trusted frequencies only, NaN elsewhere,
        shape (F,) [deg]."""
        phase = np.full(self.freq.shape, np.nan)
        keep = self.trusted
        phase[keep] = np.degrees(np.unwrap(np.angle(self.response[source][keep])))
        return phase

    def gain_error_db(self, source: str) -> np.ndarray:
        """``20 log10 |H_source / H_recording|``, NaN where untrusted, shape (F,) [dB]."""
        return self.gain_db(source) - self.gain_db("recording")

    def phase_error_deg(self, source: str) -> np.ndarray:
        """Phase of ``H_source / H_recording`` within ±180°, NaN where untrusted, shape (F,)."""
        ratio = self.response[source] / np.where(
            self.response["recording"] != 0, self.response["recording"], 1.0
        )
        return np.where(self.trusted, np.degrees(np.angle(ratio)), np.nan)

    def random_error(self) -> np.ndarray:
        """The recording's normalised random error ``ε`` per frequency, shape (F,)."""
        c = np.clip(self.coherence["recording"], 1e-12, 1.0)
        return np.sqrt(1.0 - c) / (np.sqrt(c) * np.sqrt(2.0 * self.segments))

    def gain_bounds_db(self) -> tuple[np.ndarray, np.ndarray]:
        """The recording's 95 % gain bounds, NaN where untrusted, each shape (F,) [dB] (the
        lower one is -inf where the error reaches the gain itself)."""
        spread = Z95 * self.random_error()
        gain = self.gain_db("recording")
        with np.errstate(divide="ignore", invalid="ignore"):
            lower = gain + 20 * np.log10(np.clip(1.0 - spread, 0.0, None))
        return lower, gain + 20 * np.log10(1.0 + spread)

    def phase_bound_deg(self) -> np.ndarray:
        """Half-width of the recording's 95 % phase bound, shape (F,) [deg]."""
        return np.degrees(Z95 * self.random_error())

    def band_statistics(self, source: str, band: tuple[float, float]) -> BandStatistics:
        """``source``'s errors over the trusted frequencies of ``band`` (see the module)."""
        keep = self.in_band(band)
        if not keep.any():
            nan = float("nan")
            return BandStatistics(band, 0, nan, nan, nan, nan)
        _, upper = self.gain_bounds_db()
        return BandStatistics(
            band=band,
            bins=int(keep.sum()),
            gain_error_db=_rms(self.gain_error_db(source)[keep]),
            phase_error_deg=_rms(self.phase_error_deg(source)[keep]),
            median_coherence=float(np.median(self.match[source][keep])),
            recording_bound_db=float(np.median((upper - self.gain_db("recording"))[keep])),
        )


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def welch_segment(n: int) -> int:
    """Welch segment length for ``n`` samples: ``n // 8`` rounded down to a power of two, at
    least 64 (and at most ``n``)."""
    return min(n, max(64, 2 ** int(np.floor(np.log2(max(n // 8, 64))))))


def frequency_response(
    u: np.ndarray,
    outputs: Mapping[str, np.ndarray],
    dt: float,
    input_name: str = "u",
    output_name: str = "y",
    segment: int | None = None,
    stage: str = "",
    units: tuple[str, str] = ("", ""),
) -> FrequencyResponse:
    """Welch estimates of the response of each source's output to ``u``.

    Parameters
    ----------
    u : ndarray, shape (n,)
        Excitation.
    outputs : mapping of str to ndarray, shape (n,)
        Source -> output; must contain ``"recording"``.
    dt : float
        Sample interval [s].
    input_name, output_name : str
        Names for labels.
    segment : int, optional
        Welch segment length (default: :func:`welch_segment`).
    stage : str
        Stage name, for titles.
    units : tuple of str
        Units of the input and of the output.

    Returns
    -------
    FrequencyResponse
    """
    u = np.asarray(u, dtype=float)
    if "recording" not in outputs:
        raise ValueError("outputs must contain the 'recording' source")
    n = u.size
    nperseg = min(segment or welch_segment(n), n)
    kw = {"fs": 1.0 / dt, "nperseg": nperseg, "detrend": "constant"}
    freq, p_uu = signal.welch(u, **kw)
    excited = p_uu > EXCITATION_FLOOR * p_uu.max() if p_uu.max() > 0 else np.zeros_like(p_uu, bool)
    response, coherence, match = {}, {}, {}
    recorded = np.asarray(outputs["recording"], dtype=float)
    for source, y in outputs.items():
        y = np.asarray(y, dtype=float)
        _, p_uy = signal.csd(u, y, **kw)
        response[source] = (p_uy / np.where(p_uu > 0, p_uu, 1.0))[excited]
        coherence[source] = signal.coherence(u, y, **kw)[1][excited]
        if source != "recording":
            match[source] = signal.coherence(y, recorded, **kw)[1][excited]
    return FrequencyResponse(
        stage=stage,
        input_name=input_name,
        output_name=output_name,
        input_unit=units[0],
        output_unit=units[1],
        freq=freq[excited],
        response=response,
        coherence=coherence,
        match=match,
        segments=(n - nperseg) // (nperseg // 2) + 1,
    )
