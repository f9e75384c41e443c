"""The dataset's parameter draw, as functions of (seed, sample id) and of one prior class: thin views of
``core.prior.Prior``, where the law is written (the seed paper's Table I; the ``perpendicular`` class
truncates K_u to K_eff > 0 given M_s with the other parameters of a sample unchanged).

Kept for their callers (the workflow's draw stage, the learning's trivial predictor, the posterior's
prior coordinates, the refinement and the bench): each builds the ``Prior`` of its arguments and asks it.
A bounds set that leaves no film of the class raises ConfigError (a config's fault).
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..core.parameters import DEFAULT_BOUNDS, DEFAULT_PRIOR_CLASS, LOG_SCALE, NAMES, denormalize, normalize
from ..core.prior import Prior, PriorError, UNIFORM_DRAWS
from ..core.streams import stream_rng
from ..micromag.constants import MU0

PARAMETERS = NAMES
"""Column names of the dataset files, M_s first (units: ``core.parameters.UNITS``)."""

_STREAM_NAMES = {0: "parameters", 1: "disorder"}


def sample_rng(seed: int, sample_id: int, stream: int | str = 0) -> np.random.Generator:
    """The generator of one sample for one purpose: ``stream`` 0 / "parameters" (the draw) or
    1 / "disorder" (grains and pinning); ``core.streams`` holds the derivation."""
    return stream_rng(seed, _STREAM_NAMES.get(stream, stream), sample_id)


def _prior(bounds=None, prior: str = DEFAULT_PRIOR_CLASS, exchange_length_nm=(10.0, 1.0),
           min_exchange_length_nm: float = 5.0) -> Prior:
    return Prior(prior, bounds, tuple(exchange_length_nm), min_exchange_length_nm)


def _config_errors(call):
    try:
        return call()
    except PriorError as error:
        raise ConfigError(str(error)) from None


def perpendicular_floor(Ms, bounds=None) -> np.ndarray:
    """u_f(M_s): the normalized (log) K_u below which the ``perpendicular`` class has no mass
    (``Prior.k_u_floor_u``); ConfigError where the bounds leave no perpendicular film."""
    return _config_errors(lambda: _prior(bounds, "perpendicular").k_u_floor_u(Ms))


def draw_parameters(seed: int, sample_id: int, bounds=None, exchange_length_nm=(10.0, 1.0),
                    min_exchange_length_nm: float = 5.0, prior: str = DEFAULT_PRIOR_CLASS) -> dict:
    """One sample's Hamiltonian parameters (SI) under the prior class ``prior`` (``Prior.sample``)."""
    law = _prior(bounds, prior, exchange_length_nm, min_exchange_length_nm)
    return _config_errors(lambda: law.sample(seed, sample_id))


def draw_log_density(u, names, Ms, bounds=None, exchange_length_nm=(10.0, 1.0),
                     min_exchange_length_nm: float = 5.0, prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """log p(u | M_s) of :func:`draw_parameters` in normalized units u ∈ [0, 1] (``Prior.log_prob``)."""
    law = _prior(bounds, prior, exchange_length_nm, min_exchange_length_nm)
    return _config_errors(lambda: law.log_prob(u, names, Ms))


def draw_prior_quantiles(name: str, Ms: float, qs, bounds=None, grid: int = 4001,
                         prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """Quantiles (normalized u) of one parameter's draw prior given M_s (``Prior.quantiles``)."""
    return _config_errors(lambda: _prior(bounds, prior).quantiles(name, Ms, qs, grid))


def draw_prior_cdf(name: str, u, Ms, bounds=None, prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """F(u | M_s) of one parameter's draw prior (``Prior.cdf``)."""
    return _config_errors(lambda: _prior(bounds, prior).cdf(name, u, Ms))


def draw_prior_ppf(name: str, v, Ms, bounds=None, prior: str = DEFAULT_PRIOR_CLASS) -> np.ndarray:
    """Inverse of :func:`draw_prior_cdf` (``Prior.ppf``)."""
    return _config_errors(lambda: _prior(bounds, prior).ppf(name, v, Ms))


__all__ = ["PARAMETERS", "DEFAULT_BOUNDS", "LOG_SCALE", "MU0", "sample_rng", "perpendicular_floor", "draw_parameters",
           "draw_log_density",
           "UNIFORM_DRAWS", "draw_prior_quantiles", "draw_prior_cdf", "draw_prior_ppf", "normalize", "denormalize"]
