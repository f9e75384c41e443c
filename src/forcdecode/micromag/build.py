"""A film from (configuration, parameters): the mesh of the config, the sample's disorder and
pinning, the Hamiltonian of the parameters (SI: M_s A/m, A_ex J/m, K_u J/m³, D J/m², σ_θ in
degrees, σ_K a fraction, N_pin a count on the seed paper's 256×256×2 grid).

Disorder draws come from the ``disorder`` stream of (config seed, sample id) unless an explicit
generator is given (e.g. ``core.streams.stream_rng(seed, "closed_loop_disorder", ...)``).
"""

from __future__ import annotations

import numpy as np

from ..config import defaults
from ..core.streams import stream_rng
from .disorder import FilmExtras, FilmMaterial, disordered_film
from .mesh import Mesh

REFERENCE_CELLS = 256 * 256 * 2
"""Cells of the seed paper's grid, on which N_pin counts pinning sites."""


def mesh_from_config(cfg: dict) -> Mesh:
    """The mesh of the config's ``mesh`` section (cell sizes in nm there, in m here)."""
    m = cfg["mesh"]
    return Mesh(m["nx"], m["ny"], m["nz"], m["dx_nm"] * 1e-9, m["dy_nm"] * 1e-9, m["dz_nm"] * 1e-9)


def pinning_cells(N_pin: int, mesh: Mesh, cfg: dict) -> int:
    """Number of pinning cells placed: N_pin counts sites on the paper's 256×256×2 grid; with
    ``pinning.scale_to_reference`` the same density is kept on a smaller grid."""
    if cfg["pinning"]["scale_to_reference"]:
        return int(round(N_pin * mesh.n_cells / REFERENCE_CELLS))
    return int(N_pin)


def _missing(value) -> bool:
    return value is None or (isinstance(value, float) and np.isnan(value))


def _layer_K_u_factor(value):
    """Per-layer K_u factors from params: a sequence of floats or a comma-separated string
    ("1.0,0.2", parquet-friendly); None/NaN/absent: none."""
    if _missing(value):
        return None
    if isinstance(value, str):
        return tuple(float(v) for v in value.split(","))
    return tuple(float(v) for v in value)


def build_film(cfg: dict, params: dict, sample_id: int | None = None, pinning: str | None = None,
               rng: np.random.Generator | None = None):
    """The sample's film, initial state and disorder (``disordered_film``'s triple).

    Disorder from ``rng`` if given, else from the ``disorder`` stream of (``cfg["seed"]``,
    ``sample_id``). Optional ``params`` keys (absent or NaN: off): ``K_2`` (J/m³), ``B_bias_T`` (T,
    along z), ``layer_K_u_factor`` (per-layer K_u multipliers, sequence or "f0,f1"),
    ``spacer_after_layer`` (int) and ``interlayer_coupling_J_m2`` (J/m², coupling across that spacer).
    """
    if rng is None:
        if sample_id is None:
            raise TypeError("build_film needs a sample_id (disorder stream) or an explicit rng")
        rng = stream_rng(cfg["seed"], "disorder", sample_id)
    mesh = mesh_from_config(cfg)
    spacer = params.get("spacer_after_layer")
    interlayer_J = params.get("interlayer_coupling_J_m2")
    material = FilmMaterial(Ms=params["Ms"], A_ex=params["A_ex"], K_u=params["K_u"], D=params["D"],
                            sigma_K=params["sigma_K"], sigma_theta_rad=np.radians(params["sigma_theta_deg"]),
                            n_pin=pinning_cells(params["N_pin"], mesh, cfg))
    extras = FilmExtras(K_2=float(params.get("K_2", 0.0)), B_bias_T=(0.0, 0.0, float(params.get("B_bias_T", 0.0))),
                        layer_K_u_factor=_layer_K_u_factor(params.get("layer_K_u_factor")),
                        spacer_after_layer=None if _missing(spacer) else int(spacer),
                        interlayer_coupling_J_m2=0.0 if _missing(interlayer_J) else float(interlayer_J))
    film, m0, disorder = disordered_film(mesh, material, rng, n_grains=cfg["n_grains"],
                                         pinning=pinning or cfg["pinning"]["treatment"], extras=extras,
                                         kernel_cache_dir=cfg.get("kernel_cache_dir"))
    film.preconditioner = cfg.get("minimizer", {}).get("preconditioner", "diagonal")
    return film, m0, disorder


def sweep_options(cfg: dict) -> dict:
    """Keyword arguments of the quasi-static protocol (the fields of ``forc.protocol.SweepSettings``,
    as ``quasistatic_family`` takes them) from the config's ``minimizer`` section (torque criterion,
    iteration cap, the continuation shortcuts) and the ``protocol`` section's remainder copy
    (``same_state_tol``, ``merge_curves``, ``merge_memory_MB``)."""

    mini = cfg["minimizer"]
    protocol = {**defaults("protocol"), **cfg.get("protocol", {})}
    return {"torque_tol_T": mini["torque_tol_T"], "max_iterations": mini["max_iterations"],
            "warm_step": bool(mini.get("warm_step", False)), "extrapolate": bool(mini.get("extrapolate", False)),
            "same_state_tol": float(protocol["same_state_tol"]), "merge_curves": bool(protocol["merge_curves"]),
            "merge_memory_MB": float(protocol["merge_memory_MB"])}


def slew_rate_options(cfg: dict) -> dict:
    """Keyword arguments of the ``llg`` protocol's ``forc.adaptive.SlewRate`` from the config's
    ``protocol`` section (schema defaults where absent): Gilbert damping ``alpha``, the rate's
    ``safety`` factor and its clip ``rate_min_T_per_s``/``rate_max_T_per_s`` (T/s)."""

    protocol = {**defaults("protocol"), **cfg.get("protocol", {})}
    return {key: float(protocol[key]) for key in ("alpha", "safety", "rate_min_T_per_s", "rate_max_T_per_s")}


__all__ = ["REFERENCE_CELLS", "mesh_from_config", "pinning_cells", "build_film", "sweep_options", "slew_rate_options"]
