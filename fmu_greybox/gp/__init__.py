"""Sparse Gaussian-process regression (collapsed VFE bound) on numpy/scipy.

The grey-box correctors: :class:`SparseGPR` fits, predicts (batched and single-point),
saves and loads. See ``docs/sgpr.md``.
"""

from fmu_greybox.gp.bound import CollapsedBound, Hyperparameters
from fmu_greybox.gp.inducing import (
    EquispacedInducing,
    GreedyVarianceInducing,
    InducingSelector,
    KMeansInducing,
    make_selector,
)
from fmu_greybox.gp.kernel import SquaredExponentialARD
from fmu_greybox.gp.predictive import Posterior
from fmu_greybox.gp.sgpr import SparseGPR

__all__ = [
    "CollapsedBound",
    "EquispacedInducing",
    "GreedyVarianceInducing",
    "Hyperparameters",
    "InducingSelector",
    "KMeansInducing",
    "Posterior",
    "SparseGPR",
    "SquaredExponentialARD",
    "make_selector",
]
