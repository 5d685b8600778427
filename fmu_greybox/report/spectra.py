"""Frequency-domain validation: frequency responses and coherences of recording and models.

The paper leaves frequency-domain validation open; a test-bench engineer reads a model's fit as
much from its Bode plot as from its time traces. For one excitation ``u`` (the command of the
first stage) and each stage output ``y`` this module estimates, with Welch averaging
(Hann windows, 50 % overlap):

* the frequency response ``H1(f) = P_uy(f) / P_uu(f)`` of the recording, the white-box and the
  grey-box, so that gain and phase errors show per band;
* the magnitude-squared coherence ``C_uy(f)`` of each, which says where the estimate is
  trustworthy (near 1: a linear response dominates; low: noise or non-linearity);
* the coherence between each model's output and the recorded output, ``C_ym(f)``: where it is
  near 1, the model reproduces the recording's content in that band.

Bands where the input carries little power (``P_uu`` under 1e-6 of its peak) are dropped.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy import signal

#: Input power below this fraction of its peak: band not excited, dropped.
EXCITATION_FLOOR = 1e-6


@dataclass(frozen=True)
class FrequencyResponse:
    """Frequency responses of several sources of one output to one input.

    Attributes
    ----------
    input_name, output_name : str
    freq : ndarray, shape (F,)
        Frequencies [Hz] where the input is excited.
    response : dict[str, ndarray of complex, shape (F,)]
        Source (``recording``, ``white-box``, ``grey-box``) -> ``H1`` estimate.
    coherence : dict[str, ndarray, shape (F,)]
        Source -> magnitude-squared coherence between input and output.
    match : dict[str, ndarray, shape (F,)]
        Model source -> coherence between its output and the recorded output.
    """

    input_name: str
    output_name: str
    freq: np.ndarray
    response: dict[str, np.ndarray]
    coherence: dict[str, np.ndarray]
    match: dict[str, np.ndarray]

    def band_error_db(self, source: str, f_max: float | None = None) -> float:
        """RMS gain error of ``source`` against the recording over the excited band [dB].

        Parameters
        ----------
        source : str
            A model source.
        f_max : float, optional
            Upper frequency [Hz] (default: every excited frequency).
        """
        keep = self.freq > 0
        if f_max is not None:
            keep &= self.freq <= f_max
        ref = np.abs(self.response["recording"][keep])
        got = np.abs(self.response[source][keep])
        good = (ref > 0) & (got > 0)
        if not good.any():
            return float("nan")
        return float(np.sqrt(np.mean((20 * np.log10(got[good] / ref[good])) ** 2)))


def frequency_response(
    u: np.ndarray,
    outputs: Mapping[str, np.ndarray],
    dt: float,
    input_name: str = "u",
    output_name: str = "y",
    segment: int | None = None,
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
        Welch segment length (default: ``n // 8`` rounded down to a power of two, at least 64).

    Returns
    -------
    FrequencyResponse
    """
    u = np.asarray(u, dtype=float)
    if "recording" not in outputs:
        raise ValueError("outputs must contain the 'recording' source")
    n = u.size
    nperseg = segment or max(64, 2 ** int(np.floor(np.log2(max(n // 8, 64)))))
    nperseg = min(nperseg, n)
    fs = 1.0 / dt
    kw = {"fs": fs, "nperseg": nperseg, "detrend": "constant"}
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
        input_name=input_name,
        output_name=output_name,
        freq=freq[excited],
        response=response,
        coherence=coherence,
        match=match,
    )


def stage_responses(
    u: np.ndarray,
    recorded: np.ndarray,
    models: Mapping[str, np.ndarray],
    dt: float,
    input_name: str,
    output_names: Sequence[str],
) -> list[FrequencyResponse]:
    """One :class:`FrequencyResponse` per stage output.

    Parameters
    ----------
    u : ndarray, shape (n,)
    recorded : ndarray, shape (n, Q)
    models : mapping of str to ndarray, shape (n, Q)
        Model source -> its stage outputs.
    dt : float
    input_name : str
    output_names : sequence of str, length Q
    """
    return [
        frequency_response(
            u,
            {"recording": recorded[:, q], **{k: v[:, q] for k, v in models.items()}},
            dt,
            input_name,
            name,
        )
        for q, name in enumerate(output_names)
    ]
