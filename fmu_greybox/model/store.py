"""The trained grey-box on disk: a folder of data files, never code.

Layout::

    MODEL_DIR/
      model.json           format version, project, training facts, hashes of every file
      whitebox.fmu         the white-box FMU the correctors were trained against
      stage_<NAME>.npz     corrector arrays (one pair per stage, see fmu_greybox.gp)
      stage_<NAME>.json    corrector metadata
      training_rows.npz    one digest per training row (fmu_greybox.project.fingerprint)

The named correction terms the model carries (physics found by the diagnosis, folded into the
white-box before the correctors) are plain data in ``model.json`` (``named_terms``), and so is
each stage's variance calibration (``stages[i].calibration``: ``latent_scale`` and
``residual_variance``, see :mod:`fmu_greybox.model.calibration`).

Every file's SHA-256 is recorded in ``model.json`` and checked on load, so a truncated or
tampered file is refused with a clear error; ``model.json`` also records the SHA-256 of its own
content (``manifest_sha256``, over canonical JSON without that key), so an edit of the manifest
itself is refused too. Arrays are read with ``allow_pickle=False``: nothing in the folder is ever
executed. The folder is written atomically: a failed run leaves any earlier model intact.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import shutil
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox import __version__
from fmu_greybox.atomic import atomic_dir, atomic_write
from fmu_greybox.errors import ConfigError, ModelFormatError
from fmu_greybox.fmi.archive import FmuArchive
from fmu_greybox.fmi.integrator import recorded_integrator
from fmu_greybox.gp import SparseGPR
from fmu_greybox.model.calibration import UNCALIBRATED, VarianceCalibration
from fmu_greybox.model.chain import GreyBoxChain
from fmu_greybox.model.stage import TARGET_MODES
from fmu_greybox.model.terms import Term, term_from_dict
from fmu_greybox.model.training import TrainingRecord
from fmu_greybox.model.whitebox import DEFAULT_SUBSTEPS, NamedModel
from fmu_greybox.project.config import ProjectConfig, parse_config
from fmu_greybox.project.fingerprint import RowFingerprint

#: Version written; versions read (1: no named terms; 1 and 2: no training-row digests; 1 to 3:
#: no variance calibration, read as uncalibrated; 3 and 4: digests of exact values; 1 to 4: no
#: white-box variance, read as the residual variance, and named terms on every stage from their
#: entry on; 1 to 5: a corrector for every stage, where 6 has none (``stem`` null) for a stage
#: passed through from the start).
FORMAT_VERSION = 6
READABLE_VERSIONS = (1, 2, 3, 4, 5, 6)
MANIFEST = "model.json"
WHITEBOX = "whitebox.fmu"
#: First version whose stages carry their variance calibration.
CALIBRATED_VERSION = 4
#: Digests of the training rows, by which ``validate`` recognises training data.
TRAINING_ROWS = "training_rows.npz"
#: First version whose row digests are of values cut at the rows' full scale (``scale``).
SCALED_DIGESTS_VERSION = 5
#: Key of ``model.json`` holding the SHA-256 of the rest of its content.
MANIFEST_HASH = "manifest_sha256"
#: First version that always records :data:`MANIFEST_HASH` (it came late in version 1, so a
#: version 1 folder may lack it; one of a later version without it was edited).
HASHED_VERSION = 2
_RETRAIN = "Retrain the model or restore the folder from a copy"


@dataclass
class GreyBoxModel:
    """A trained grey-box: project, chain of fitted correctors, white-box FMU, training facts.

    Attributes
    ----------
    config : ProjectConfig
        The project (its white-box entry points at :attr:`whitebox_fmu`).
    chain : GreyBoxChain
        Fitted chain.
    whitebox_fmu : Path
        The white-box FMU file.
    dt : float
        Communication step [s].
    training : TrainingRecord
        Facts about the training: recording hash, rows used, target spreads per stage, ...
    terms : list of Term
        Named correction terms folded into the white-box before the correctors (from a
        diagnosis); empty for a plain white-box.
    substeps : int
        FMU steps per communication step while a feedback term is active.
    trained_rows : RowFingerprint or None
        The rows the correctors were trained on, and the calibration recordings' rows σ was
        calibrated on (:class:`~fmu_greybox.project.fingerprint.RowFingerprint`; of exact values
        in format versions 3 and 4); ``None`` for a folder written before they were kept
        (format versions 1 and 2).
    """

    config: ProjectConfig
    chain: GreyBoxChain
    whitebox_fmu: Path
    dt: float
    training: TrainingRecord = field(default_factory=TrainingRecord)
    terms: list[Term] = field(default_factory=list)
    substeps: int = DEFAULT_SUBSTEPS
    trained_rows: RowFingerprint | None = None

    @property
    def target_std(self) -> Mapping[str, float]:
        """Standard deviation of each stage's training target (for normalised RMSE)."""
        return self.training.target_std

    def stage_terms(self, q: int) -> list[Term]:
        """The named terms acting on stage ``q``'s outputs."""
        return [t for t in self.terms if t.acts_at(q)]

    def contents(self) -> dict[str, str]:
        """Stage -> what the model computes there, in words: ``"white-box"``, then
        ``" + named terms"`` where terms act on the stage, then ``" + corrector"`` where its
        corrector is used."""
        return {
            stage.name: "white-box"
            + (" + named terms" if self.stage_terms(q) else "")
            + (" + corrector" if self.chain.active_[q] else "")
            for q, stage in enumerate(self.chain.stages)
        }

    @property
    def kind(self) -> str:
        """What the model is, in words: ``"grey-box"`` when some corrector is used, else
        ``"white-box + named terms"`` or ``"white-box"``."""
        if self.chain.active_.any():
            return "grey-box"
        return "white-box + named terms" if self.terms else "white-box"

    def output_stages(self, outputs: Sequence[str]) -> list[int]:
        """The stage each white-box output is read at: a stage's output at its stage, any
        other output at the last stage (after every named term)."""
        stage_of = {s.config.whitebox_output: s.stage_index for s in self.chain.stages}
        last = len(self.chain.stages) - 1
        return [stage_of.get(name, last) for name in outputs]

    def whitebox(
        self,
        archive: FmuArchive,
        inputs: Sequence[str],
        outputs: Sequence[str],
        start_values: Mapping[str, float],
        start_time: float,
        instance_name: str = "whitebox",
    ) -> NamedModel:
        """The white-box with the model's named terms, as the correctors were trained on it.

        Parameters
        ----------
        archive : FmuArchive
            The white-box FMU (:attr:`whitebox_fmu`, opened).
        inputs, outputs : sequence of str
            FMU inputs and outputs exchanged per step. A stage's output is read from the
            instance of its stage; any other output from the last stage's.
        start_values : mapping
            Initial input values.
        start_time : float
            [s]

        Returns
        -------
        NamedModel
        """
        return NamedModel(
            archive,
            inputs,
            outputs,
            self.dt,
            self.terms,
            self.output_stages(outputs),
            self.config.parameters,
            start_values,
            start_time,
            self.substeps,
            instance_name,
            recorded_integrator(self.training.whitebox),
        )


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def manifest_digest(manifest: Mapping[str, Any]) -> str:
    """SHA-256 of a manifest's content without its own hash, as canonical JSON.

    Parameters
    ----------
    manifest : mapping
        The parsed ``model.json``.

    Returns
    -------
    str
        Hex digest; independent of key order and whitespace.
    """
    body = {key: value for key, value in manifest.items() if key != MANIFEST_HASH}
    text = json.dumps(body, sort_keys=True, separators=(",", ":"), ensure_ascii=True)
    return hashlib.sha256(text.encode("ascii")).hexdigest()


def save_model(model: GreyBoxModel, out_dir: str | Path) -> Path:
    """Write the model folder atomically.

    Returns
    -------
    Path
        The folder.
    """
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        tmp = Path(tmp)
        shutil.copyfile(model.whitebox_fmu, tmp / WHITEBOX)
        if model.trained_rows is not None:
            with atomic_write(tmp / TRAINING_ROWS, "wb") as f:
                np.savez(f, **_fingerprint_arrays(model.trained_rows))
        stages = []
        for stage, corrector in zip(model.chain.stages, model.chain.correctors_, strict=True):
            stem = None if corrector is None else f"stage_{stage.name}"
            if corrector is not None:
                corrector.save(tmp / stem)
            stages.append(
                {
                    "name": stage.name,
                    "stem": stem,
                    "features": model.chain.feature_names(stage.stage_index),
                    "active": bool(model.chain.active_[stage.stage_index]),
                    "target_mode": stage.target_mode,
                    "feature_low": model.chain.feature_bounds_[stage.stage_index][0].tolist(),
                    "feature_high": model.chain.feature_bounds_[stage.stage_index][1].tolist(),
                    "calibration": dataclasses.asdict(model.chain.calibration_[stage.stage_index]),
                }
            )
        files = sorted(p.name for p in tmp.iterdir())
        manifest = {
            "format_version": FORMAT_VERSION,
            "tool": f"fmu-greybox {__version__}",
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "project": model.config.to_dict(),
            "target_mode": model.chain.target_mode,
            "dt": model.dt,
            "stages": stages,
            "training": model.training.to_dict(),
            "named_terms": {
                "terms": [t.to_dict() for t in model.terms],
                "substeps": model.substeps,
            },
            "whitebox_sha256": file_sha256(tmp / WHITEBOX),
            "files": {name: file_sha256(tmp / name) for name in files},
        }
        manifest[MANIFEST_HASH] = manifest_digest(manifest)
        with atomic_write(tmp / MANIFEST, "w") as f:
            json.dump(manifest, f, indent=2, sort_keys=True)
    return out_dir


def read_manifest(model_dir: str | Path) -> dict[str, Any]:
    """Read ``model.json`` and check the format version and every file's hash.

    Raises
    ------
    ModelFormatError
        Missing folder or manifest, unknown version, an edited or malformed manifest, a file it
        does not list, a missing file or a hash mismatch; the message names the file.
    """
    model_dir = Path(model_dir)
    path = model_dir / MANIFEST
    if not path.is_file():
        raise ModelFormatError(
            f"{model_dir}: no {MANIFEST}; not a model folder written by 'fmu-greybox train'"
        )
    try:
        manifest = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ModelFormatError(f"{path}: corrupt manifest ({exc}); {_RETRAIN}") from exc
    if not isinstance(manifest, dict):
        raise ModelFormatError(
            f"{path}: holds a JSON {type(manifest).__name__}, not the object 'fmu-greybox train' "
            f"writes; {_RETRAIN}"
        )
    version = manifest.get("format_version")
    if version not in READABLE_VERSIONS:
        newer = isinstance(version, int) and version > FORMAT_VERSION
        mend = (
            "It was written by a newer fmu-greybox: upgrade this one (pip install -U "
            "fmu-greybox), or retrain the model with it"
            if newer
            else "Retrain the model with this version"
        )
        raise ModelFormatError(
            f"{path}: format version {version!r}; this tool reads versions "
            f"{', '.join(map(str, READABLE_VERSIONS))}. {mend}"
        )
    recorded = manifest.get(MANIFEST_HASH)
    if recorded is None and version >= HASHED_VERSION:
        raise ModelFormatError(
            f"{path}: no {MANIFEST_HASH!r}, which every model folder of format version "
            f"{version} records; it was removed, so edits of the manifest could not be told. "
            f"{_RETRAIN}"
        )
    if recorded is not None and recorded != manifest_digest(manifest):
        raise ModelFormatError(
            f"{path}: content does not match the hash it recorded at training; the manifest "
            f"was edited or corrupted. {_RETRAIN}"
        )
    _check_manifest(path, manifest)
    for name, expected in manifest["files"].items():
        file = model_dir / name
        if not file.is_file():
            raise ModelFormatError(
                f"{model_dir}: {name} is missing; the model folder is "
                "incomplete, retrain or restore it"
            )
        if file_sha256(file) != expected:
            raise ModelFormatError(
                f"{file}: content does not match the hash recorded at "
                "training; the file was modified or corrupted. Retrain or "
                "restore the model folder"
            )
    return manifest


def _training(path: Path, training: Mapping[str, Any]) -> TrainingRecord:
    """The training record of a manifest, of this format or an older one (a plain dict)."""
    try:
        return TrainingRecord.from_dict(training)
    except ModelFormatError as exc:
        raise ModelFormatError(f"{path}: {exc}") from exc


def _check_manifest(path: Path, manifest: dict[str, Any]) -> None:
    """The fields :func:`load_model` reads exist with the right types; files are all hashed."""

    def bad(field_name: str, what: str) -> ModelFormatError:
        return ModelFormatError(
            f"{path}: field {field_name!r} {what}; the manifest was edited or corrupted. {_RETRAIN}"
        )

    for key, kind in (("project", dict), ("training", dict), ("target_mode", str)):
        if not isinstance(manifest.get(key), kind):
            raise bad(key, f"is missing or not a {kind.__name__}")
    dt = manifest.get("dt")
    number = isinstance(dt, int | float) and not isinstance(dt, bool)
    if not (number and math.isfinite(dt) and dt > 0):
        raise bad("dt", "is missing or not a positive number of seconds")
    files = manifest.get("files")
    if not isinstance(files, dict) or not all(
        _plain_name(n) and isinstance(h, str) for n, h in files.items()
    ):
        raise bad("files", "is missing or not a table of file name -> SHA-256 in this folder")
    stages = manifest.get("stages")
    if not isinstance(stages, list) or not stages:
        raise bad("stages", "is missing or not a list of stages")
    needed = [WHITEBOX, *([TRAINING_ROWS] if manifest["format_version"] >= 3 else [])]
    for i, stage in enumerate(stages):
        where = f"stages[{i}]"
        if not isinstance(stage, dict) or not isinstance(stage.get("name"), str):
            raise bad(where, "is not a stage with a name")
        if not isinstance(stage.get("active"), bool):
            raise bad(f"{where}.active", "is missing or not true/false")
        if stage.get("stem") is None and _without_corrector(manifest, stage):
            continue
        if not _plain_name(stage.get("stem")):
            raise bad(f"{where}.stem", "is not a file name in this folder")
        needed += [f"{stage['stem']}.npz", f"{stage['stem']}.json"]
    unlisted = [name for name in needed if name not in files]
    if unlisted:
        raise bad("files", f"lists no hash for {', '.join(unlisted)}")


#: First version in which a stage passed through from the start may have no corrector.
OPTIONAL_CORRECTOR_VERSION = 6


def _without_corrector(manifest: Mapping[str, Any], stage: Mapping[str, Any]) -> bool:
    """Whether a stage may come without a corrector: one passed through (not ``active``) in
    a folder of version :data:`OPTIONAL_CORRECTOR_VERSION` or later."""
    return manifest["format_version"] >= OPTIONAL_CORRECTOR_VERSION and not stage["active"]


def _plain_name(name: Any) -> bool:
    """Whether ``name`` is a file name inside the folder (no folder part, not hidden)."""
    return isinstance(name, str) and bool(name) and Path(name).name == name and name[0] != "."


def load_model(model_dir: str | Path) -> GreyBoxModel:
    """Load a model folder written by :func:`save_model`, checking every hash.

    Raises
    ------
    ModelFormatError
        See :func:`read_manifest`; also when the stored project is no longer valid.
    """
    model_dir = Path(model_dir)
    manifest = read_manifest(model_dir)
    raw = dict(manifest["project"])
    raw["whitebox"] = {**raw.get("whitebox", {}), "fmu": str((model_dir / WHITEBOX).resolve())}
    try:
        config = parse_config(raw, None)
    except Exception as exc:
        raise ModelFormatError(f"{model_dir}: stored project is invalid: {exc}") from exc
    stages = manifest["stages"]
    try:
        chain = GreyBoxChain(config, manifest["target_mode"])
        for layout, stage in zip(chain.stages, stages, strict=False):
            # the target training chose (version 1 folders: the project's)
            layout.target_mode = stage.get("target_mode", layout.target_mode)
            if layout.target_mode not in TARGET_MODES:
                raise ValueError(f"stage {stage.get('name')!r}: unknown target_mode")
        if [s["name"] for s in stages] != chain.stage_names:
            raise ValueError(
                f"stages {[s['name'] for s in stages]} differ from the project's "
                f"{chain.stage_names}"
            )
        bounds = [_feature_bounds(s, len(chain.feature_names(i))) for i, s in enumerate(stages)]
        calibrated = manifest["format_version"] >= CALIBRATED_VERSION
        calibration = [_calibration(s, calibrated) for s in stages]
    except (ConfigError, KeyError, TypeError, ValueError) as exc:
        raise ModelFormatError(
            f"{model_dir / MANIFEST}: the stages do not fit the stored project ({exc}); {_RETRAIN}"
        ) from exc
    chain.correctors_ = [
        None if s.get("stem") is None else _load_corrector(model_dir / s["stem"]) for s in stages
    ]
    chain.active_ = np.array([s["active"] for s in stages], dtype=bool)
    chain.feature_bounds_ = bounds
    chain.calibration_ = calibration
    terms, substeps = _named_terms(model_dir / MANIFEST, manifest, len(stages))
    return GreyBoxModel(
        config=config,
        chain=chain,
        whitebox_fmu=model_dir / WHITEBOX,
        dt=float(manifest["dt"]),
        training=_training(model_dir / MANIFEST, manifest["training"]),
        terms=terms,
        substeps=substeps,
        trained_rows=(
            _trained_rows(model_dir, manifest["format_version"] >= SCALED_DIGESTS_VERSION)
            if TRAINING_ROWS in manifest["files"]
            else None
        ),
    )


def _fingerprint_arrays(rows: RowFingerprint) -> dict[str, np.ndarray]:
    """The arrays of ``training_rows.npz``: ``digests`` and, for cut values, ``scale``."""
    arrays = {"digests": np.unique(rows.digests)}
    if rows.scale is not None:
        arrays["scale"] = rows.scale
    return arrays


def _trained_rows(model_dir: Path, scaled: bool) -> RowFingerprint:
    """The training-row digests, checked to be a vector of uint64, with the columns' full
    scale (a vector of positive finite floats) where the folder's version cuts values."""
    path = model_dir / TRAINING_ROWS
    try:
        with np.load(path, allow_pickle=False) as arrays:
            digests = arrays["digests"]
            scale = arrays["scale"] if scaled else None
    except (OSError, ValueError, KeyError) as exc:
        raise ModelFormatError(
            f"{path}: not a readable .npz of row digests ({exc}); {_RETRAIN}"
        ) from exc
    if digests.ndim != 1 or digests.dtype != np.uint64:
        raise ModelFormatError(
            f"{path}: holds {digests.dtype} of shape {digests.shape}, not a vector of uint64 row "
            f"digests; {_RETRAIN}"
        )
    if scale is not None and not (
        scale.ndim == 1
        and scale.dtype == np.float64
        and scale.size > 0
        and np.all(np.isfinite(scale))
        and np.all(scale > 0)
    ):
        raise ModelFormatError(
            f"{path}: its 'scale' ({scale.dtype} of shape {scale.shape}) is not a vector of "
            f"positive finite floats, one per column of a row; {_RETRAIN}"
        )
    return RowFingerprint(digests, scale)


def _named_terms(path: Path, manifest: Mapping[str, Any], n_stages: int) -> tuple[list[Term], int]:
    """The manifest's named terms and sub-steps (none in a version 1 folder)."""
    named = manifest.get("named_terms", {"terms": [], "substeps": DEFAULT_SUBSTEPS})
    try:
        terms = [term_from_dict(t) for t in named["terms"]]
        substeps = int(named["substeps"])
        stages = [t.entry for t in terms] + [q for t in terms for q in t.stages_off]
        if substeps < 1 or any(not 0 <= q < n_stages for q in stages):
            raise ValueError("sub-steps below 1 or a term acting at a stage that is not there")
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFormatError(
            f"{path}: field 'named_terms' is unusable ({exc}); {_RETRAIN}"
        ) from exc
    return terms, substeps


def _feature_bounds(stage: Mapping[str, Any], n_features: int) -> np.ndarray:
    """A stage's recorded feature range as shape (2, n_features), checked finite and ordered."""
    low = np.asarray(stage["feature_low"], dtype=np.float64)
    high = np.asarray(stage["feature_high"], dtype=np.float64)
    if low.shape != (n_features,) or high.shape != (n_features,):
        raise ValueError(
            f"stage {stage['name']!r} has feature bounds of shapes {low.shape} and {high.shape}, "
            f"expected ({n_features},) each"
        )
    if not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(low <= high)):
        raise ValueError(f"stage {stage['name']!r} has non-finite or inverted feature bounds")
    return np.array([low, high])


#: The calibration's optional third number (:class:`VarianceCalibration`).
WHITEBOX_VARIANCE = "whitebox_variance"


def _calibration(stage: Mapping[str, Any], calibrated: bool) -> VarianceCalibration:
    """A stage's variance calibration, checked finite and non-negative; uncalibrated in a
    folder written before calibration existed (``calibrated`` false), required after."""
    stored = stage.get("calibration")
    if stored is None and not calibrated:
        return UNCALIBRATED
    names = {"latent_scale", "residual_variance"}
    if not isinstance(stored, Mapping) or not names <= set(stored) <= names | {WHITEBOX_VARIANCE}:
        raise ValueError(
            f"stage {stage['name']!r} has a calibration that is not a table of latent_scale, "
            "residual_variance and (optional) whitebox_variance"
        )
    values = [stored["latent_scale"], stored["residual_variance"]]
    if stored.get(WHITEBOX_VARIANCE) is not None:  # kept from format 5 on
        values.append(stored[WHITEBOX_VARIANCE])
    if not all(
        isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
        for v in values
    ):
        raise ValueError(
            f"stage {stage['name']!r} has a calibration with a value that is not a finite "
            "number >= 0"
        )
    return VarianceCalibration(*(float(v) for v in values))


def _load_corrector(stem: Path) -> SparseGPR:
    """A stage's corrector; settings or fit facts its loader cannot use name the file."""
    try:
        return SparseGPR.load(stem)
    except (KeyError, TypeError, ValueError) as exc:
        raise ModelFormatError(
            f"{stem}.json: settings or fit facts unusable ({type(exc).__name__}: {exc}); {_RETRAIN}"
        ) from exc
