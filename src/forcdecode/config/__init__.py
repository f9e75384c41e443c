"""The configuration: ONE schema, its defaults, and the shipped default configurations.

``defaults()`` is the single source of default values (``defaults("learning")`` the learning
defaults); ``load_config(path)`` reads a YAML/JSON configuration, fills the schema's defaults and
validates it, raising :class:`~forcdecode.core.errors.ConfigError` that names the key and the file.

Package data, one copy each: ``schemas/`` is the repository's ``workflow/schemas/`` (where the
workflow validates its config) and ``defaults/`` its top-level ``config/`` (``config.yaml``,
``cluster.yaml``, ``paper.yaml``, ``test.yaml``), reached through relative symlinks in a checkout and copied into
a wheel by setuptools.
"""

from __future__ import annotations

import copy
import functools
from pathlib import Path

from ..core.errors import ConfigError
from ..core.parameters import DEFAULT_BOUNDS, k_u_floor

_HERE = Path(__file__).resolve().parent
SCHEMA_PATH = _HERE / "schemas" / "config.schema.yaml"
"""The configuration schema (JSON Schema 2020-12, YAML)."""
CONFIGS_DIR = _HERE / "defaults"
"""The shipped configurations."""

SHIPPED_CONFIGS = ("config", "cluster", "paper", "test")
"""Names of the shipped configurations: laptop default, the cluster default (the information map's most
informative film), the seed paper's scale, tiny CI."""


@functools.lru_cache(maxsize=1)
def _schema() -> dict:
    import yaml

    return yaml.safe_load(SCHEMA_PATH.read_text())


def schema() -> dict:
    """The configuration schema as a dict (a copy: callers may change it)."""
    return copy.deepcopy(_schema())


def _fill_defaults(instance: dict, node: dict) -> dict:
    """Set every absent property that has a ``default`` (recursively into objects), as Snakemake's
    ``validate(..., set_default=True)`` does."""
    for key, sub in node.get("properties", {}).items():
        if "default" in sub and key not in instance:
            instance[key] = copy.deepcopy(sub["default"])
        if isinstance(instance.get(key), dict) and "properties" in sub:
            _fill_defaults(instance[key], sub)
    return instance


def defaults(section: str | None = None) -> dict:
    """The schema's defaults: the whole configuration (keys without a default, such as
    ``n_samples``, absent) or one section (``defaults("learning")``). A fresh dict each call."""
    full = _fill_defaults({}, _schema())
    if section is None:
        return full
    if section not in full or not isinstance(full[section], dict):
        raise KeyError(f"no configuration section {section!r} with defaults (sections: "
                       f"{', '.join(k for k, v in full.items() if isinstance(v, dict))})")
    return full[section]


def validate_config(cfg: dict, source: str = "the configuration") -> dict:
    """Fill the schema's defaults into ``cfg`` (in place) and validate it; returns ``cfg``.
    A violation raises ConfigError naming the key (dotted path) and ``source``."""
    from jsonschema import Draft202012Validator
    from jsonschema.exceptions import best_match

    if not isinstance(cfg, dict):
        raise ConfigError(f"{source}: a configuration is a mapping of keys, got {type(cfg).__name__}")
    _fill_defaults(cfg, _schema())
    error = best_match(Draft202012Validator(_schema()).iter_errors(cfg))
    if error is not None:
        key = ".".join(str(p) for p in error.absolute_path) or "(top level)"
        raise ConfigError(f"{source}: invalid value at {key}: {error.message}")
    _check_prior(cfg, source)
    return cfg


def _check_prior(cfg: dict, source: str) -> None:
    """The prior class must have mass at every M_s of the bounds (``core.parameters.k_u_floor``)."""

    bounds = {**DEFAULT_BOUNDS, **(cfg.get("bounds") or {})}
    try:
        k_u_floor(max(bounds["Ms"]), cfg.get("prior", "paper"), bounds)
    except ValueError as error:
        raise ConfigError(f"{source}: invalid value at prior: {error}") from None


def load_config(path) -> dict:
    """A configuration file (YAML or JSON) read, defaults filled and validated against the schema.
    A missing or unreadable file, or one that does not validate, raises ConfigError naming it."""
    import yaml

    path = Path(path)
    try:
        cfg = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ConfigError(f"config file {path} not found") from None
    except (OSError, UnicodeDecodeError) as error:
        raise ConfigError(f"cannot read config file {path}: {error}") from None
    except yaml.YAMLError as error:
        raise ConfigError(f"config file {path} is not valid YAML: {error}") from None
    return validate_config(cfg if cfg is not None else {}, source=f"config file {path}")


LATE_DEFAULTS = {"realisations": 1, "prior": "paper"}
"""Dataset (physics) keys added after datasets had been made, with the value every earlier dataset
implicitly had. A config that holds one of them at this value means what a config without the key
meant, so the dataset's config.json and config hash leave it out (``dataset_config``)."""


def dataset_config(cfg: dict) -> dict:
    """``cfg`` (a copy) without the ``LATE_DEFAULTS`` keys that hold their default value.

    Why: the schema fills ``realisations: 1`` into every config, but datasets made before the key
    existed (and the models trained on them, which carry the dataset's config hash) have none; left
    out at 1, a dataset's config.json, its config hash and (since realisation 0 is the sample's
    original disorder stream) every family stay bit for bit what they were; the same for
    ``prior: paper`` (the draw of every dataset before the key). Any other value is kept, so that it
    changes the hash. Used by the workflow's ``resolve_config`` and by ``dataset.merge``."""
    return {k: v for k, v in cfg.items() if not (k in LATE_DEFAULTS and v == LATE_DEFAULTS[k])}


def realisations(cfg: dict) -> int:
    """Disorder realisations averaged per sample (``realisations``; absent: 1)."""
    return int(cfg.get("realisations", LATE_DEFAULTS["realisations"]))


def film_thickness_nm(cfg: dict) -> float:
    """The simulated film's thickness (nm): nz layers of dz_nm."""
    return float(cfg["mesh"]["nz"] * cfg["mesh"]["dz_nm"])


def with_thickness(cfg: dict, thickness_nm: float) -> dict:
    """A copy of ``cfg`` whose film is ``thickness_nm`` thick: one layer of cells dz_nm = thickness_nm (a
    perpendicular thin film is uniform through its thickness at these scales; the demagnetising kernel
    integrates over the layer exactly, ``micromag.demag``). ConfigError for a non-positive thickness."""
    try:
        value = float(thickness_nm)
    except (TypeError, ValueError):
        raise ConfigError(f"film thickness must be a number of nm, got {thickness_nm!r}") from None
    if not value > 0 or value == float("inf"):
        raise ConfigError(f"film thickness must be a positive number of nm, got {thickness_nm!r}")
    out = copy.deepcopy(cfg)
    out["mesh"] = {**cfg["mesh"], "nz": 1, "dz_nm": value}
    return out


def shipped_config(name: str = "config") -> Path:
    """Path of the shipped configuration ``name``: config (laptop), cluster (the cluster default),
    paper (the seed paper's scale) or test (tiny, CI)."""
    if name not in SHIPPED_CONFIGS:
        raise KeyError(f"no shipped configuration {name!r} (one of {', '.join(SHIPPED_CONFIGS)})")
    return CONFIGS_DIR / f"{name}.yaml"


__all__ = ["SCHEMA_PATH", "CONFIGS_DIR", "SHIPPED_CONFIGS", "LATE_DEFAULTS", "schema", "defaults",
           "validate_config", "load_config", "dataset_config", "realisations", "shipped_config", "film_thickness_nm",
           "with_thickness"]
