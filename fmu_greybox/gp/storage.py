"""Sparse-GP model files: ``<stem>.npz`` (arrays) + ``<stem>.json`` (metadata). No pickle.

The JSON names the format and its version, the estimator settings, fit diagnostics and
the SHA-256 of the ``.npz`` file; the ``.npz`` holds every number prediction needs (scalars
as 0-d arrays), so a loaded model predicts bit for bit like the saved one.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from fmu_greybox.errors import ModelFormatError
from fmu_greybox.gp.predictive import Posterior

FORMAT_NAME = "fmu-greybox/sparse-gpr"
FORMAT_VERSION = 1
SUPPORTED_VERSIONS = (1,)

VECTOR_FIELDS = ("x_mean", "x_scale", "lengthscales", "mean_weights")
MATRIX_FIELDS = ("inducing_points", "chol_uu", "chol_b")
SCALAR_FIELDS = ("y_mean", "y_scale", "signal_variance", "noise_variance")
ARRAY_FIELDS = VECTOR_FIELDS + MATRIX_FIELDS + SCALAR_FIELDS
JSON_KEYS = ("format", "format_version", "arrays_sha256", "settings", "fit")


def paths(path_stem: str | Path) -> tuple[Path, Path]:
    """The ``.npz`` and ``.json`` paths of a model stem (the stem may contain dots)."""
    stem = str(path_stem)
    return Path(stem + ".npz"), Path(stem + ".json")


def save(
    path_stem: str | Path,
    posterior: Posterior,
    settings: dict[str, Any],
    fit_info: dict[str, Any],
) -> tuple[Path, Path]:
    """Write a model.

    Parameters
    ----------
    path_stem : str or Path
        Files are ``<stem>.npz`` and ``<stem>.json``; the folder must exist.
    posterior : Posterior
    settings : dict
        Estimator constructor arguments (JSON-serialisable).
    fit_info : dict
        Fit diagnostics (JSON-serialisable).

    Returns
    -------
    npz_path, json_path : Path
    """
    npz_path, json_path = paths(path_stem)
    arrays = {name: np.asarray(getattr(posterior, name), dtype=np.float64) for name in ARRAY_FIELDS}
    with npz_path.open("wb") as fh:
        np.savez(fh, **arrays)
    meta = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "arrays": npz_path.name,
        "arrays_sha256": _sha256(npz_path),
        "kernel": "squared_exponential_ard",
        "input_dim": posterior.input_dim,
        "n_inducing": posterior.n_inducing,
        "settings": settings,
        "fit": fit_info,
    }
    json_path.write_text(json.dumps(meta, indent=2) + "\n", encoding="utf-8")
    return npz_path, json_path


def load(path_stem: str | Path) -> tuple[Posterior, dict[str, Any], dict[str, Any]]:
    """Read a model written by :func:`save`.

    Returns
    -------
    posterior : Posterior
    settings : dict
    fit_info : dict

    Raises
    ------
    ModelFormatError
        Naming the file and what is wrong with it.
    """
    npz_path, json_path = paths(path_stem)
    meta = _read_metadata(json_path)
    if not npz_path.is_file():
        raise ModelFormatError(f"{npz_path}: array file missing (it belongs with {json_path})")
    if _sha256(npz_path) != meta["arrays_sha256"]:
        raise ModelFormatError(
            f"{npz_path}: contents do not match the SHA-256 recorded in {json_path.name}; "
            "the file was modified or belongs to another model — save the model again"
        )
    arrays = _read_arrays(npz_path)
    posterior = _posterior(arrays, npz_path)
    return posterior, dict(meta["settings"]), dict(meta["fit"])


def _read_metadata(json_path: Path) -> dict[str, Any]:
    if not json_path.is_file():
        raise ModelFormatError(f"{json_path}: model metadata file not found")
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ModelFormatError(f"{json_path}: not readable as JSON ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT_NAME:
        raise ModelFormatError(f"{json_path}: not a sparse-GP model file (format {FORMAT_NAME!r})")
    version = meta.get("format_version")
    if version not in SUPPORTED_VERSIONS:
        raise ModelFormatError(
            f"{json_path}: unknown format version {version!r}; this fmu-greybox reads "
            f"version(s) {', '.join(map(str, SUPPORTED_VERSIONS))} — refit the model or "
            "upgrade fmu-greybox"
        )
    missing = [key for key in JSON_KEYS if key not in meta]
    if missing:
        raise ModelFormatError(f"{json_path}: metadata lacks {', '.join(missing)}")
    return meta


def _read_arrays(npz_path: Path) -> dict[str, np.ndarray]:
    try:
        with np.load(npz_path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise ModelFormatError(f"{npz_path}: not a readable .npz array file ({exc})") from exc
    missing = [name for name in ARRAY_FIELDS if name not in arrays]
    if missing:
        raise ModelFormatError(f"{npz_path}: missing array(s) {', '.join(missing)}")
    return arrays


def _posterior(arrays: dict[str, np.ndarray], npz_path: Path) -> Posterior:
    """Check shapes and dtypes, then build the posterior."""
    m, d = arrays["inducing_points"].shape if arrays["inducing_points"].ndim == 2 else (-1, -1)
    expected = {name: (d,) for name in ("x_mean", "x_scale", "lengthscales")}
    expected |= {
        "mean_weights": (m,),
        "inducing_points": (m, d),
        "chol_uu": (m, m),
        "chol_b": (m, m),
    }
    expected |= {name: () for name in SCALAR_FIELDS}
    for name, shape in expected.items():
        a = arrays[name]
        if a.dtype != np.float64 or a.shape != shape or not np.all(np.isfinite(a)):
            raise ModelFormatError(
                f"{npz_path}: array {name!r} should be finite float64 of shape {shape}, "
                f"got {a.dtype} {a.shape}"
            )
    vectors = {name: arrays[name] for name in VECTOR_FIELDS + MATRIX_FIELDS}
    scalars = {name: float(arrays[name]) for name in SCALAR_FIELDS}
    return Posterior(**vectors, **scalars)


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()
