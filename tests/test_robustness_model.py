"""Corrupt, tampered and hostile model folders (issue 7, section 4).

tests/test_greybox.py checks one flipped byte in an ``.npz``, a missing file and an unknown format
version; tests/test_sgpr.py the corrector files on their own. Here: a byte flipped anywhere in any
file of the folder (``model.json`` included), every file missing in turn, edits of ``model.json``
that keep it valid JSON, a pickle planted where an ``.npz`` belongs with every hash recomputed (it
is refused and never executed), paths escaping the folder, and manifests whose structure is
broken after their hashes were made to match.
"""

from __future__ import annotations

import dataclasses
import json
import pickle
import shutil
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fmu_greybox.errors import ModelFormatError
from fmu_greybox.fmi.archive import open_fmu
from fmu_greybox.model.calibration import UNCALIBRATED
from fmu_greybox.model.store import (
    FORMAT_VERSION,
    MANIFEST,
    MANIFEST_HASH,
    file_sha256,
    load_model,
    manifest_digest,
    save_model,
)
from fmu_greybox.model.training import TRAINING_FORMAT
from fmu_greybox.project.config import parse_config
from fmu_greybox.synth.actuator import FlightTestProfile, SynthRequest, synthesise
from fmu_greybox.workflow.train import train_model

REFERENCE = Path(__file__).resolve().parents[1] / "bench_configs" / "hydraulic_actuator.toml"
FUZZ = settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)


@pytest.fixture(scope="module")
def saved(whitebox_fmu: Path, truth_fmu: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A small trained model folder (do not modify: copy it with :func:`copy_of`)."""
    request = SynthRequest(
        effects={"gain_error": 0.1}, seed=5, noise=0.0, profile=FlightTestProfile(duration=0.5)
    )
    with open_fmu(truth_fmu) as truth, open_fmu(whitebox_fmu) as whitebox:
        recording = synthesise(truth, whitebox, request)
    raw = tomllib.loads(REFERENCE.read_text(encoding="utf-8"))
    raw["whitebox"]["fmu"] = str(whitebox_fmu)
    raw["gp"].update(inducing=8, max_iter=3)
    model = train_model(parse_config(raw, REFERENCE), recording)
    return save_model(model, tmp_path_factory.mktemp("saved") / "model")


def copy_of(saved: Path, folder: Path) -> Path:
    """A private copy of the saved model folder."""
    target = folder / "model"
    shutil.copytree(saved, target)
    return target


def read(folder: Path) -> dict[str, Any]:
    return json.loads((folder / MANIFEST).read_text(encoding="utf-8"))


def write_rehashed(folder: Path, manifest: dict[str, Any]) -> None:
    """Write ``manifest`` with every file hash and its own hash recomputed, as a forger would."""
    files = manifest.get("files")
    for name in list(files) if isinstance(files, dict) else []:
        if (folder / name).is_file():
            manifest["files"][name] = file_sha256(folder / name)
    manifest[MANIFEST_HASH] = manifest_digest(manifest)
    (folder / MANIFEST).write_text(json.dumps(manifest, indent=2), encoding="utf-8")


def refused(folder: Path, pattern: str) -> ModelFormatError:
    with pytest.raises(ModelFormatError, match=pattern) as info:
        load_model(folder)
    return info.value


def test_saved_manifest_records_its_own_hash(saved: Path) -> None:
    manifest = read(saved)
    assert manifest[MANIFEST_HASH] == manifest_digest(manifest)
    assert set(manifest["files"]) == {p.name for p in saved.iterdir()} - {MANIFEST}
    load_model(saved)


@FUZZ
@given(data=st.data())
def test_a_flipped_byte_anywhere_is_refused_naming_the_file(
    saved: Path, tmp_path_factory: pytest.TempPathFactory, data: st.DataObject
) -> None:
    folder = copy_of(saved, tmp_path_factory.mktemp("flip"))
    name = data.draw(st.sampled_from(sorted(p.name for p in folder.iterdir())))
    content = bytearray((folder / name).read_bytes())
    at = data.draw(st.integers(0, len(content) - 1))
    content[at] ^= data.draw(st.integers(1, 255))
    (folder / name).write_bytes(bytes(content))
    if name == MANIFEST:
        try:
            edited = json.loads(content.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError):
            edited = None
        if edited == read(saved):
            return  # whitespace changed only: the same manifest, rightly accepted
    error = refused(folder, name)
    assert str(folder / name) in str(error) or f": {name} is missing" in str(error), str(error)
    assert "Retrain" in str(error) or "retrain" in str(error) or "save the model" in str(error)


def test_each_missing_file_is_named(saved: Path, tmp_path: Path) -> None:
    for name in sorted(p.name for p in saved.iterdir()):
        folder = copy_of(saved, tmp_path / name)
        (folder / name).unlink()
        pattern = "not a model folder" if name == MANIFEST else rf"{name} is missing"
        error = refused(folder, pattern)
        assert str(folder) in str(error)


@pytest.mark.parametrize(
    ("edit", "pattern"),
    [
        (lambda m: m.update(dt=0.5), "content does not match the hash it recorded"),
        (lambda m: m["stages"].pop(), "content does not match the hash it recorded"),
        (lambda m: m["files"].pop("stage_RAM.npz"), "content does not match the hash"),
        (lambda m: m.update(format_version="1"), "format version '1'"),
        (
            lambda m: m.update(format_version=FORMAT_VERSION + 1),
            f"format version {FORMAT_VERSION + 1}; this tool reads versions "
            + ", ".join(str(v) for v in range(1, FORMAT_VERSION + 1))
            + r"\. It was written by a newer fmu-greybox: upgrade this one",
        ),
    ],
    ids=["dt", "stage removed", "hash removed", "version as text", "newer version"],
)
def test_valid_json_edits_of_the_manifest_are_refused(
    saved: Path, tmp_path: Path, edit: Callable[[dict], Any], pattern: str
) -> None:
    folder = copy_of(saved, tmp_path)
    manifest = read(folder)
    edit(manifest)
    (folder / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")
    error = refused(folder, pattern)
    assert str(folder / MANIFEST) in str(error)


def test_a_current_manifest_without_its_own_hash_is_refused(saved: Path, tmp_path: Path) -> None:
    """Issue 42, item 8: deleting ``manifest_sha256`` switched the tamper check off (factors
    edited 100 times loaded, validated and exported). Every folder of format 2 on records it;
    only one of format 1 (written before it existed) loads without it."""
    folder = copy_of(saved, tmp_path)
    manifest = read(folder)
    del manifest[MANIFEST_HASH]
    manifest["stages"][0]["calibration"]["latent_scale"] *= 100.0  # the edit it would have hidden
    (folder / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")
    error = refused(
        folder,
        rf"model\.json: no 'manifest_sha256', which every model folder of "
        rf"format version {FORMAT_VERSION} records; it was removed",
    )
    assert str(folder / MANIFEST) in str(error)
    for version in range(2, FORMAT_VERSION):
        manifest["format_version"] = version
        (folder / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")
        refused(
            folder, rf"no 'manifest_sha256', which every model folder of format version {version}"
        )
    manifest["format_version"] = 1
    (folder / MANIFEST).write_text(json.dumps(manifest), encoding="utf-8")
    assert load_model(folder).dt == manifest["dt"]


class _Payload:
    """Unpickling this creates a marker file: proof that a pickle was executed."""

    marker: Path

    def __reduce__(self) -> tuple:
        return (Path.touch, (self.marker,))


def test_planted_pickle_is_refused_and_never_executed(saved: Path, tmp_path: Path) -> None:
    folder = copy_of(saved, tmp_path)
    marker = tmp_path / "pickle_was_executed"
    payload = _Payload()
    payload.marker = marker
    (folder / "stage_RAM.npz").write_bytes(pickle.dumps(payload))
    meta = json.loads((folder / "stage_RAM.json").read_text(encoding="utf-8"))
    meta["arrays_sha256"] = file_sha256(folder / "stage_RAM.npz")
    (folder / "stage_RAM.json").write_text(json.dumps(meta), encoding="utf-8")
    write_rehashed(folder, read(folder))
    refused(folder, r"stage_RAM\.npz: not a readable \.npz array file \(.*pickled")
    assert not marker.exists()


def test_npz_holding_a_pickled_object_array_is_refused(saved: Path, tmp_path: Path) -> None:
    folder = copy_of(saved, tmp_path)
    marker = tmp_path / "pickle_was_executed"
    payload = _Payload()
    payload.marker = marker
    with np.load(folder / "stage_EHV.npz") as data:
        arrays = {k: data[k] for k in data.files}
    arrays["mean_weights"] = np.array([payload], dtype=object)
    np.savez(folder / "stage_EHV.npz", **arrays)
    meta = json.loads((folder / "stage_EHV.json").read_text(encoding="utf-8"))
    meta["arrays_sha256"] = file_sha256(folder / "stage_EHV.npz")
    (folder / "stage_EHV.json").write_text(json.dumps(meta), encoding="utf-8")
    write_rehashed(folder, read(folder))
    refused(folder, r"stage_EHV\.npz: not a readable \.npz array file")
    assert not marker.exists()


@pytest.mark.parametrize(
    ("edit", "pattern"),
    [
        (lambda meta: meta.update(format_version=7), r"stage_ITFV\.json: unknown format version 7"),
        (lambda meta: meta["settings"].update(bogus=1), r"stage_ITFV\.json: settings or fit facts"),
        (lambda meta: meta["fit"].pop("bound"), r"stage_ITFV\.json: .*KeyError: 'bound'"),
        (lambda meta: meta["fit"].update(n_iter="many"), r"stage_ITFV\.json: .*ValueError"),
    ],
    ids=["format version", "unknown setting", "fit fact missing", "fit fact not a number"],
)
def test_stage_file_edited_then_rehashed(
    saved: Path, tmp_path: Path, edit: Callable[[dict], Any], pattern: str
) -> None:
    folder = copy_of(saved, tmp_path)
    meta = json.loads((folder / "stage_ITFV.json").read_text(encoding="utf-8"))
    edit(meta)
    (folder / "stage_ITFV.json").write_text(json.dumps(meta), encoding="utf-8")
    write_rehashed(folder, read(folder))
    refused(folder, pattern)


def _set_stage(index: int, **fields: Any) -> Callable[[dict], Any]:
    return lambda m: m["stages"][index].update(fields)


@pytest.mark.parametrize(
    ("edit", "pattern"),
    [
        (lambda m: m.clear(), r"field 'project' is missing"),
        (lambda m: m.update(dt=-1e-3), r"field 'dt' is missing or not a positive number"),
        (lambda m: m.update(dt=True), r"field 'dt'"),
        (lambda m: m.update(files=["whitebox.fmu"]), r"field 'files' is missing or not a table"),
        (lambda m: m["files"].update({"../outside.txt": "0" * 64}), r"field 'files'"),
        (lambda m: m["files"].update({"/etc/passwd": "0" * 64}), r"field 'files'"),
        (lambda m: m["files"].pop("stage_RAM.json"), r"'files' lists no hash for stage_RAM\.json"),
        (lambda m: m["files"].pop("whitebox.fmu"), r"'files' lists no hash for whitebox\.fmu"),
        (lambda m: m.update(stages={}), r"field 'stages' is missing or not a list"),
        (_set_stage(0, stem="../../elsewhere/stage_EHV"), r"'stages\[0\]\.stem' is not a file"),
        (_set_stage(1, stem=".hidden"), r"'stages\[1\]\.stem' is not a file name"),
        (_set_stage(2, active="yes"), r"'stages\[2\]\.active' is missing or not true/false"),
        (_set_stage(0, name="SPOOL"), r"stages do not fit the stored project.*SPOOL"),
        (_set_stage(1, feature_low=[0.0]), r"stages do not fit.*feature bounds of shape"),
        (_set_stage(1, feature_low="low"), r"stages do not fit the stored project"),
        (
            _set_stage(2, calibration={"latent_scale": 1.0, "residual_variance": -2.0}),
            r"stage 'ITFV' has a calibration with a value that is not a finite number >= 0",
        ),
        (
            _set_stage(0, calibration={"latent_scale": 1.0}),
            r"stage 'EHV' has a calibration that is not a table",
        ),
        (lambda m: m["stages"].pop(), r"stages do not fit the stored project"),
        (lambda m: m.update(target_mode="delta"), r"stages do not fit.*'delta' is not one of"),
        (lambda m: m["project"]["gp"].update(inducing=0), r"stored project is invalid"),
        (
            lambda m: m.update(named_terms={"terms": [{"kind": "Exec"}], "substeps": 4}),
            r"'named_terms' is unusable \(unknown term kind 'Exec'",
        ),
        (
            lambda m: m.update(
                named_terms={"terms": [{"kind": "InputOffset", "entry": 7}], "substeps": 4}
            ),
            r"'named_terms' is unusable .*a term acting at a stage that is not there",
        ),
        (lambda m: m.update(named_terms={"terms": []}), r"'named_terms' is unusable"),
    ],
)
def test_rehashed_but_malformed_manifest_is_refused(
    saved: Path, tmp_path: Path, edit: Callable[[dict], Any], pattern: str
) -> None:
    """Hashes recomputed after the edit, so only the structure checks can catch it."""
    folder = copy_of(saved, tmp_path)
    manifest = read(folder)
    edit(manifest)
    manifest["format_version"] = FORMAT_VERSION
    write_rehashed(folder, manifest)
    error = refused(folder, pattern)
    assert str(folder) in str(error)


def test_manifest_that_is_not_an_object(saved: Path, tmp_path: Path) -> None:
    folder = copy_of(saved, tmp_path)
    (folder / MANIFEST).write_text("[1, 2, 3]", encoding="utf-8")
    refused(folder, r"model\.json: holds a JSON list, not the object 'fmu-greybox train' writes")
    (folder / MANIFEST).write_bytes(b"\xff\xfe{}")
    refused(folder, r"model\.json: corrupt manifest")


def test_a_folder_written_before_calibration_loads_uncalibrated(
    saved: Path, tmp_path: Path
) -> None:
    """Formats 1 to 3 knew no calibration: their stages report the propagated variance
    (a = 1, b = 0); from format 4 on a stage without one is refused."""
    folder = copy_of(saved, tmp_path)
    manifest = read(folder)
    for stage in manifest["stages"]:
        del stage["calibration"]
    manifest["format_version"] = FORMAT_VERSION
    write_rehashed(folder, manifest)
    refused(folder, r"stage '\w+' has a calibration that is not a table")
    manifest["format_version"] = 3
    write_rehashed(folder, manifest)
    old = load_model(folder)
    assert old.chain.calibration_ == [UNCALIBRATED] * 3
    assert load_model(saved).chain.calibration_ != old.chain.calibration_
    chain = old.chain
    state = chain.start(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, len(chain.exo_names))))
    chain.plan().step(state, np.zeros(len(chain.exo_names)), np.zeros(3))
    np.testing.assert_array_equal(state.out_var, state.latent_var)


def test_the_training_record_is_written_versioned_and_an_older_dict_still_loads(
    saved: Path, tmp_path: Path
) -> None:
    """model.json keeps training's keys plus the record's format version; a folder whose
    ``"training"`` is the plain dict of an earlier version (no format version) loads with the
    same facts."""
    written = read(saved)["training"]
    assert written["format_version"] == TRAINING_FORMAT
    current = load_model(saved).training
    assert current.to_dict() == written and current.train_rows == written["train_rows"]
    folder = copy_of(saved, tmp_path)
    manifest = read(folder)
    del manifest["training"]["format_version"]
    write_rehashed(folder, manifest)
    older = load_model(folder).training
    assert older.format_version == 0
    assert dataclasses.replace(older, format_version=TRAINING_FORMAT) == current
    manifest["training"]["format_version"] = TRAINING_FORMAT + 1
    write_rehashed(folder, manifest)
    refused(folder, r"model\.json: the training record is of format")


def _paths(value: Any, prefix: tuple = ()) -> list[tuple]:
    """Every key path into nested JSON objects and arrays (the root excluded)."""
    if not isinstance(value, dict | list):
        return []
    found = []
    for key, inner in value.items() if isinstance(value, dict) else enumerate(value):
        found.append((*prefix, key))
        found += _paths(inner, (*prefix, key))
    return found


JSON_VALUES = st.recursive(
    st.none()
    | st.booleans()
    | st.integers(-(2**70), 2**70)
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.text(max_size=12),
    lambda inner: (
        st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=6,
)


@FUZZ
@given(data=st.data())
def test_any_manifest_field_set_to_any_value_and_rehashed(
    saved: Path, tmp_path_factory: pytest.TempPathFactory, data: st.DataObject
) -> None:
    """A forger sets any field of model.json, at any depth, to any JSON value and recomputes
    every hash: the folder loads or is refused naming it, never with another exception."""
    folder = copy_of(saved, tmp_path_factory.mktemp("field"))
    manifest = read(folder)
    path = data.draw(st.sampled_from([p for p in _paths(manifest) if p[0] != MANIFEST_HASH]))
    parent = manifest
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = data.draw(JSON_VALUES)
    write_rehashed(folder, manifest)
    try:
        load_model(folder)
    except ModelFormatError as error:
        assert str(folder) in str(error), str(error)


@FUZZ
@given(
    digests=st.one_of(
        st.lists(st.integers(0, 2**64 - 1), max_size=5).map(lambda v: np.array(v, np.uint64)),
        st.lists(st.floats(), min_size=1, max_size=5).map(np.array),
        st.lists(st.integers(-5, 5), min_size=1, max_size=4).map(
            lambda v: np.array(v, np.int64).reshape(-1, 1)
        ),
    ),
    key=st.sampled_from(["digests", "rows"]),
)
def test_training_row_digests_replaced_by_any_array(
    saved: Path, tmp_path_factory: pytest.TempPathFactory, digests: np.ndarray, key: str
) -> None:
    """training_rows.npz holding any array under any name, hashes recomputed: a vector of
    uint64 under 'digests' loads; anything else is refused naming the file."""
    folder = copy_of(saved, tmp_path_factory.mktemp("digests"))
    with np.load(saved / "training_rows.npz") as arrays:
        scale = arrays["scale"]
    np.savez(folder / "training_rows.npz", scale=scale, **{key: digests})
    write_rehashed(folder, read(folder))
    if key == "digests" and digests.dtype == np.uint64 and digests.ndim == 1:
        loaded = load_model(folder).trained_rows
        np.testing.assert_array_equal(loaded.digests, digests)
        np.testing.assert_array_equal(loaded.scale, scale)
    else:
        refused(folder, r"training_rows\.npz: ")


@FUZZ
@given(
    scale=st.one_of(
        st.lists(st.floats(allow_nan=True), max_size=5).map(lambda v: np.array(v, np.float64)),
        st.lists(st.integers(-5, 5), min_size=1, max_size=4).map(lambda v: np.array(v)),
    ),
)
def test_training_row_scale_replaced_by_any_array(
    saved: Path, tmp_path_factory: pytest.TempPathFactory, scale: np.ndarray
) -> None:
    """The columns' full scale of format 5, replaced and rehashed: only a vector of positive
    finite floats loads; anything else (NaN, zero, negative, integers, empty) is refused."""
    folder = copy_of(saved, tmp_path_factory.mktemp("scale"))
    with np.load(saved / "training_rows.npz") as arrays:
        digests = arrays["digests"]
    np.savez(folder / "training_rows.npz", digests=digests, scale=scale)
    write_rehashed(folder, read(folder))
    good = scale.dtype == np.float64 and scale.size > 0 and bool(np.all(np.isfinite(scale)))
    if good and bool(np.all(scale > 0)):
        np.testing.assert_array_equal(load_model(folder).trained_rows.scale, scale)
    else:
        refused(folder, r"training_rows\.npz: its 'scale' .* is not a vector of positive finite")
