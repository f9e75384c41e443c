"""The one route from a Hamiltonian to a FORC family on the config's grid: ``simulate_family(cfg, params)``.

The dataset (``dataset.simulate``), the loop's re-simulations and inference (``infer.resimulate``) all
simulate through here, so the protocol switch is written once: ``cfg["protocol"]["name"]`` "quasistatic"
(each field point relaxed to its energy minimum, ``forc.protocol.quasistatic_family``) or "llg" (the
Landau–Lifshitz–Gilbert equation integrated at a finite field slew rate with slaved pinning cells,
``forc.adaptive.adaptive_family``). Fields μ0H in tesla, ``n_fields`` points on [−B_max, +B_max].
"""

from __future__ import annotations

import numpy as np

from ..core.errors import ConfigError
from ..micromag.build import build_film, slew_rate_options, sweep_options
from .adaptive import SlewRate, adaptive_family
from .protocol import quasistatic_family

PROTOCOLS = ("quasistatic", "llg")
"""The FORC protocols a config may name (``protocol.name``)."""


def protocol_name(cfg: dict) -> str:
    """The config's FORC protocol: "quasistatic" (default) or "llg"; ConfigError for another name."""
    name = cfg.get("protocol", {}).get("name", "quasistatic")
    if name not in PROTOCOLS:
        raise ConfigError(f"unknown FORC protocol {name!r} (quasistatic or llg)")
    return name


def simulate_family(cfg: dict, params: dict, sample_id: int | None = None, rng: np.random.Generator | None = None):
    """The FORC family (``ForcFamily``: ⟨m_z⟩ curves on the grid, the descending branch, counters) of one
    disorder realisation of ``params`` (SI): disorder from ``rng``, else from the ``disorder`` stream of
    ``sample_id`` (``micromag.build.build_film``)."""
    n_fields, B_max_T = cfg["field"]["n_fields"], cfg["field"]["B_max_T"]
    if protocol_name(cfg) == "llg":
        film, m0, _ = build_film(cfg, params, sample_id, pinning="slaved", rng=rng)
        family = adaptive_family(film, m0, n_fields=n_fields, B_max_T=B_max_T,
                                 settings=SlewRate(**slew_rate_options(cfg)))
        family.stats.setdefault("relaxations", 0)
        family.stats.setdefault("unconverged", 0)
        return family
    film, m0, _ = build_film(cfg, params, sample_id, rng=rng)
    return quasistatic_family(film, m0, n_fields=n_fields, B_max_T=B_max_T, **sweep_options(cfg))


__all__ = ["PROTOCOLS", "protocol_name", "simulate_family"]
