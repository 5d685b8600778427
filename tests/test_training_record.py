"""The training record (:class:`~fmu_greybox.model.training.TrainingRecord`): typed, frozen,
versioned, and written to ``model.json`` in the keys training has always used."""

from __future__ import annotations

import dataclasses

import pytest

from fmu_greybox.errors import ModelFormatError
from fmu_greybox.model.training import TRAINING_FORMAT, TrainingRecord

#: The keys ``workflow/train.py`` wrote under ``"training"`` before the record existed.
WRITTEN_KEYS = {
    "recording_sha256",
    "recording_source",
    "n_samples",
    "train_rows",
    "dt",
    "input_ranges",
    "target_std",
    "target_unit",
    "bounds",
    "free_run_check",
    "target_selection",
    "calibration_check",
    "calibration_recordings",
    "whitebox",
    "whitebox_source",
    "whitebox_sha256",
    "seconds",
}

#: A ``"training"`` of an older model folder: no format version, no ``train_rows``,
#: ``input_ranges`` nor ``calibration_check``, and a key this version does not read.
OLDER = {
    "recording_sha256": "ab" * 32,
    "recording_source": "rec.csv",
    "n_samples": 400,
    "dt": 0.001,
    "target_std": {"EHV": 0.5, "RAM": 2.0},
    "target_unit": {"EHV": "mm", "RAM": "mm"},
    "bounds": {"EHV": -1.0, "RAM": -2.0},
    "free_run_check": {"EHV": {"active": True}},
    "target_selection": {},
    "calibration_recordings": [],
    "whitebox_source": "wb.fmu",
    "whitebox_sha256": "cd" * 32,
    "seconds": 1.5,
    "shipped": "correctors",
}


def test_an_older_dict_reads_with_missing_facts_empty_and_unknown_keys_kept() -> None:
    record = TrainingRecord.from_dict(OLDER)
    assert record.format_version == 0
    assert record.target_std == {"EHV": 0.5, "RAM": 2.0} and record.seconds == 1.5
    assert record.train_rows is None and record.parts is None
    assert record.input_ranges == {} and record.calibration_check == {}
    assert record.extra == {"shipped": "correctors"}
    written = record.to_dict()
    assert written["format_version"] == TRAINING_FORMAT
    assert {k: written[k] for k in OLDER} == OLDER
    assert "train_rows" not in written and "parts" not in written


def test_a_fresh_record_writes_the_same_keys_and_reads_back_equal() -> None:
    record = TrainingRecord.from_dict({**OLDER, "train_rows": 200, "shipped": None})
    record = dataclasses.replace(record, extra={}, format_version=TRAINING_FORMAT)
    assert set(record.to_dict()) == WRITTEN_KEYS | {"format_version"}
    with_parts = dataclasses.replace(record, parts={"best": "terms"})
    assert set(with_parts.to_dict()) == WRITTEN_KEYS | {"format_version", "parts"}
    assert TrainingRecord.from_dict(with_parts.to_dict()) == with_parts


def test_the_record_is_frozen() -> None:
    with pytest.raises(dataclasses.FrozenInstanceError):
        TrainingRecord().seconds = 1.0  # type: ignore[misc]


@pytest.mark.parametrize("version", [TRAINING_FORMAT + 1, "1", 1.0, True, None])
def test_a_newer_or_malformed_format_is_refused(version: object) -> None:
    with pytest.raises(ModelFormatError, match="training record is of format"):
        TrainingRecord.from_dict({**OLDER, "format_version": version})
