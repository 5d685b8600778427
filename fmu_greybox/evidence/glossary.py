"""The reports' glossary: each term of art defined once, at the foot of the page, and linked
where a table or a sentence uses it (:func:`term`)."""

from __future__ import annotations

from fmu_greybox.evidence.html import Html, escape

#: Key -> (the term as shown, its definition in plain words), in the order the glossary lists
#: them.
GLOSSARY: dict[str, tuple[str, str]] = {
    "independent-recording": (
        "independent recording",
        "A recording of the same system that the model never saw in training (the demo "
        "records one with another seed).",
    ),
    "held-out": (
        "held-out rows",
        "Rows of a recording set aside and not used to fit the model, so that scoring on them "
        "shows how it does on data it has not seen.",
    ),
    "free-run": (
        "free run",
        "The model simulated from the recorded inputs only, its correctors fed the model's own "
        "earlier outputs rather than the recorded ones, as it runs on a bench. Errors may build "
        "up over time: the honest test.",
    ),
    "nrmse": (
        "nRMSE, error score",
        "The RMSE (root mean square of recording minus model, in the signal's unit) divided by "
        "the spread (standard deviation) of the recorded signal in training: 0 is perfect, 1 "
        "is no better than a constant. The parts' error score is its mean over the stages.",
    ),
    "named-terms": (
        "named terms",
        "Physical effects the diagnosis found and named (a friction, a leakage, a supply "
        "pressure drooping with flow), added to the white-box as equations with the magnitudes "
        "it fitted.",
    ),
    "corrector": (
        "corrector",
        "Per stage, a sparse Gaussian-process model learnt from the recording that adds what "
        "the white-box (with its named terms) still misses. A corrector switched off (passed "
        "through) leaves its stage to the white-box.",
    ),
    "parts": (
        "parts",
        "The three candidate models: correctors alone on the plain white-box, named terms "
        "alone, and named terms with correctors. The diagnosis compares them quickly on the "
        "rows it held out; training compares them again on a longer stretch, and that "
        "comparison decides what ships.",
    ),
    "sigma": (
        "σ (uncertainty)",
        "The grey-box's standard deviation at each moment, calibrated on free runs so that "
        "about 95 % of a recording like the training one lies inside ±1.96σ (and 68 % inside "
        "±1σ); the exported FMU's _std outputs.",
    ),
    "independent-rows": (
        "independent rows",
        "A free run's errors come in slow waves, so neighbouring rows repeat one another. The "
        "independent rows are how many rows of separate evidence they amount to: with few, a "
        "share inside the band is known only roughly.",
    ),
    "error-ratio": (
        "error ratio k",
        "The grey-box's RMSE on this recording divided by its RMSE on the free runs σ was "
        "calibrated on. Near 1, ±1.96σ should hold about 95 %; at k it holds about "
        "erf(1.96 / k / √2) of Gaussian errors (82 % at k = 1.46, 68 % at k = 1.96).",
    ),
    "thin-evidence": (
        "thin evidence",
        "A pass whose evidence cannot vouch for its limits: the share's 95 % interval, or the "
        "range a band calibrated on so few independent rows holds on recordings like them, "
        "reaches beyond the limits. It passed here; another recording may not.",
    ),
    "coherence": (
        "coherence, trusted frequencies",
        "How closely an output follows an input linearly at each frequency, from 0 to 1. The "
        "recording's estimate is trusted where its coherence reaches 0.6; only those "
        "frequencies are drawn and scored.",
    ),
    "noise-ratio": (
        "RMS / noise",
        "A stage's white-box error (RMS) divided by the estimated sensor noise: near 1, the "
        "white-box matches within noise there.",
    ),
    "inherited": (
        "inherited",
        "The share of a stage's white-box error explained by the errors of the stages before "
        "it in the chain. A stage whose error is mostly inherited is not where the mismatch "
        "starts.",
    ),
}


def term(key: str, text: str | None = None) -> Html:
    """A link to the glossary's definition of ``key`` (:data:`GLOSSARY`), reading ``text``
    (the term as the glossary shows it by default).

    Raises
    ------
    KeyError
        For a term the glossary does not define.
    """
    shown = GLOSSARY[key][0] if text is None else text
    return Html(f"<a class='term' href='#glossary-{key}'>{escape(shown)}</a>")


def glossary_section() -> str:
    """The glossary: every term of :data:`GLOSSARY` with its definition, each an anchor."""
    entries = "".join(
        f"<dt id='glossary-{key}'>{escape(shown)}</dt><dd>{escape(text)}</dd>"
        for key, (shown, text) in GLOSSARY.items()
    )
    return f"<h2 id='glossary'>Glossary</h2><dl>{entries}</dl>"
