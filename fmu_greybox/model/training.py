"""What training hands on with a model: the facts of its training run, as one typed record.

:class:`TrainingRecord` is written to ``model.json`` under ``"training"`` with the keys it has
always had, plus its ``format_version``; a model folder written before the record existed (a
plain dict, any of its keys possibly missing) reads into one, missing facts left empty, and
keys this version does not know are kept and written back.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import Any

from fmu_greybox.errors import ModelFormatError

#: Version of the training record's layout in ``model.json``; a dict without one is version 0.
TRAINING_FORMAT = 1


@dataclass(frozen=True)
class TrainingRecord:
    """Facts about a model's training run (``model.json``'s ``"training"``).

    Mappings are keyed by stage name unless said otherwise; an empty mapping, a ``None`` or an
    empty text means a model folder written before the fact was recorded (``model.json`` holds
    no key for a ``None``).

    Attributes
    ----------
    recording_sha256 : str
        SHA-256 of the training recording.
    recording_source : str
        Where the training recording was read from.
    n_samples : int or None
        Rows of the training recording.
    train_rows : int or None
        Leading rows the correctors were trained on.
    dt : float or None
        Communication step of the training recording [s].
    input_ranges : mapping of str to list of float
        FMU input name -> ``[low, high]`` over the training rows
        (:func:`~fmu_greybox.model.domain.training_ranges`).
    target_std : mapping of str to float
        Standard deviation of each stage's target over the training rows.
    target_unit : mapping of str to str
        Unit of each stage's target.
    bounds : mapping of str to float
        Each stage's final VFE bound.
    free_run_check : mapping of str to dict
        Each stage's free-run check (``GreyBoxChain.free_run_check_``).
    target_selection : mapping of str to dict
        Each stage's choice of targets (``GreyBoxChain.selection_``).
    calibration_check : mapping of str to dict
        Each stage's check of its variance calibration (``GreyBoxChain.calibration_check_``).
    calibration_recordings : list of dict
        ``sha256``, ``source`` and ``n_samples`` of each recording σ was calibrated on.
    whitebox_source : str
        The white-box FMU file trained with.
    whitebox_sha256 : str
        Its SHA-256.
    whitebox : mapping of str to object
        Its kind, and for model exchange how it was integrated
        (:func:`~fmu_greybox.fmi.integrator.whitebox_facts`).
    seconds : float or None
        Wall time of the training [s].
    parts : mapping or None
        The comparison of the model's parts (``PartsComparison.to_dict``) when trained with
        named terms, else ``None``.
    extra : mapping of str to object
        Keys of an older or edited ``"training"`` this version does not read, kept as found.
    format_version : int
        :data:`TRAINING_FORMAT` when written by this version; 0 for a plain dict of an older one.
    """

    recording_sha256: str = ""
    recording_source: str = ""
    n_samples: int | None = None
    train_rows: int | None = None
    dt: float | None = None
    input_ranges: Mapping[str, list[float]] = field(default_factory=dict)
    target_std: Mapping[str, float] = field(default_factory=dict)
    target_unit: Mapping[str, str] = field(default_factory=dict)
    bounds: Mapping[str, float] = field(default_factory=dict)
    free_run_check: Mapping[str, Any] = field(default_factory=dict)
    target_selection: Mapping[str, Any] = field(default_factory=dict)
    calibration_check: Mapping[str, Any] = field(default_factory=dict)
    calibration_recordings: list[dict[str, Any]] = field(default_factory=list)
    whitebox_source: str = ""
    whitebox_sha256: str = ""
    whitebox: Mapping[str, Any] = field(default_factory=dict)
    seconds: float | None = None
    parts: Mapping[str, Any] | None = None
    extra: Mapping[str, Any] = field(default_factory=dict)
    format_version: int = TRAINING_FORMAT

    @classmethod
    def from_dict(cls, training: Mapping[str, Any]) -> TrainingRecord:
        """The record of a ``model.json``'s ``"training"``, of this format or an older one.

        Raises
        ------
        ModelFormatError
            The record is of a newer format than this version reads.
        """
        version = training.get("format_version", 0)
        if not isinstance(version, int) or isinstance(version, bool) or version > TRAINING_FORMAT:
            raise ModelFormatError(
                f"the training record is of format {version!r}; this fmu-greybox reads up to "
                f"{TRAINING_FORMAT}: update fmu-greybox or retrain the model"
            )
        facts = {f.name for f in fields(cls)} - {"extra", "format_version"}
        return cls(
            **{key: value for key, value in training.items() if key in facts},
            extra={
                key: value
                for key, value in training.items()
                if key not in facts and key != "format_version"
            },
            format_version=version,
        )

    def to_dict(self) -> dict[str, Any]:
        """The record as ``model.json`` stores it: the keys training has always written (none
        for a fact that is ``None``), the older keys kept in :attr:`extra`, and
        ``format_version``."""
        written = {
            f.name: getattr(self, f.name)
            for f in fields(self)
            if f.name != "extra" and getattr(self, f.name) is not None
        }
        return {**self.extra, **written, "format_version": TRAINING_FORMAT}
