"""The trained grey-box on disk: a folder of data files, never code.

Layout::

    MODEL_DIR/
      model.json           format version, project, training facts, hashes of every file
      whitebox.fmu         the white-box FMU the correctors were trained against
      stage_<NAME>.npz     corrector arrays (one pair per stage, see fmu_greybox.gp)
      stage_<NAME>.json    corrector metadata

Every file's SHA-256 is recorded in ``model.json`` and checked on load, so a truncated or
tampered file is refused with a clear error. The folder is written atomically: a failed run
leaves any earlier model intact.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import __version__
from .atomic import atomic_dir, atomic_write
from .config import ProjectConfig, parse_config
from .errors import ModelFormatError
from .gp import SparseGPR
from .greybox import GreyBoxChain

FORMAT_VERSION = 1
MANIFEST = "model.json"
WHITEBOX = "whitebox.fmu"


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
    training : dict
        Facts about the training: recording hash, rows used, target spreads per stage, ...
    """

    config: ProjectConfig
    chain: GreyBoxChain
    whitebox_fmu: Path
    dt: float
    training: dict[str, Any] = field(default_factory=dict)

    @property
    def target_std(self) -> dict[str, float]:
        """Standard deviation of each stage's training target (for normalised RMSE)."""
        return self.training["target_std"]


def file_sha256(path: Path) -> str:
    """SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


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
        stages = []
        for stage, corrector in zip(model.chain.stages, model.chain.correctors_, strict=True):
            stem = f"stage_{stage.name}"
            corrector.save(tmp / stem)
            stages.append(
                {
                    "name": stage.name,
                    "stem": stem,
                    "features": model.chain.feature_names(stage.stage_index),
                    "active": bool(model.chain.active_[stage.stage_index]),
                    "feature_low": model.chain.feature_bounds_[stage.stage_index][0].tolist(),
                    "feature_high": model.chain.feature_bounds_[stage.stage_index][1].tolist(),
                }
            )
        files = sorted(p.name for p in tmp.iterdir())
        manifest = {
            "format_version": FORMAT_VERSION,
            "tool": f"fmu-greybox {__version__}",
            "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
            "project": model.config.raw,
            "target_mode": model.chain.target_mode,
            "dt": model.dt,
            "stages": stages,
            "training": model.training,
            "whitebox_sha256": file_sha256(tmp / WHITEBOX),
            "files": {name: file_sha256(tmp / name) for name in files},
        }
        with atomic_write(tmp / MANIFEST, "w") as f:
            json.dump(manifest, f, indent=2, sort_keys=True)
    return out_dir


def read_manifest(model_dir: str | Path) -> dict[str, Any]:
    """Read ``model.json`` and check the format version and every file's hash.

    Raises
    ------
    ModelFormatError
        Missing folder or manifest, unknown version, missing file or hash mismatch.
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
        raise ModelFormatError(f"{path}: corrupt manifest ({exc}); retrain the model") from exc
    version = manifest.get("format_version")
    if version != FORMAT_VERSION:
        raise ModelFormatError(
            f"{path}: format version {version!r}; this tool reads version "
            f"{FORMAT_VERSION}. Retrain the model with this version"
        )
    for name, expected in manifest.get("files", {}).items():
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
    chain = GreyBoxChain(config, manifest["target_mode"])
    chain.correctors_ = [SparseGPR.load(model_dir / s["stem"]) for s in manifest["stages"]]
    chain.active_ = np.array([s["active"] for s in manifest["stages"]], dtype=bool)
    chain.feature_bounds_ = [
        np.array([s["feature_low"], s["feature_high"]], dtype=np.float64)
        for s in manifest["stages"]
    ]
    return GreyBoxModel(
        config=config,
        chain=chain,
        whitebox_fmu=model_dir / WHITEBOX,
        dt=float(manifest["dt"]),
        training=manifest["training"],
    )
