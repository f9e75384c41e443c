"""Per-sample simulation: build the film from its parameters, screen it, simulate its FORC family.

Failures are results: a sample whose simulation diverges (non-finite magnetization) or raises is
recorded with status "failed" and the reason; it never stops the chunk.
"""

from __future__ import annotations

import time
import traceback

import numpy as np

from ..forc.adaptive import SlewRate, adaptive_family
from ..forc.protocol import descending_branch, quasistatic_family
from ..forc.raster import rasterize_grid_family
from ..micromag import Mesh, disordered_film
from .params import sample_rng

REFERENCE_CELLS = 256 * 256 * 2
"""Cells of the seed paper's grid, on which N_pin counts pinning sites."""


def mesh_from_config(cfg: dict) -> Mesh:
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


def build_film(cfg: dict, params: dict, sample_id: int, pinning: str | None = None):
    """The sample's film, initial state and disorder. Optional ``params`` keys (absent or NaN: off):
    ``K_2`` (J/m³), ``B_bias_T`` (T, along z), ``layer_K_u_factor`` (per-layer K_u multipliers,
    sequence or "f0,f1"), ``spacer_after_layer`` (int) and ``interlayer_coupling_J_m2`` (J/m²,
    coupling across that spacer)."""
    mesh = mesh_from_config(cfg)
    spacer = params.get("spacer_after_layer")
    interlayer_J = params.get("interlayer_coupling_J_m2")
    rng = sample_rng(cfg["seed"], sample_id, 1)
    return disordered_film(
        mesh, Ms=params["Ms"], A_ex=params["A_ex"], K_u=params["K_u"], D=params["D"],
        sigma_K=params["sigma_K"], sigma_theta_rad=np.radians(params["sigma_theta_deg"]),
        n_pin=pinning_cells(params["N_pin"], mesh, cfg), rng=rng, n_grains=cfg["n_grains"],
        pinning=pinning or cfg["pinning"]["treatment"], kernel_cache_dir=cfg.get("kernel_cache_dir"),
        K_2=float(params.get("K_2", 0.0)), B_bias_T=(0.0, 0.0, float(params.get("B_bias_T", 0.0))),
        layer_K_u_factor=_layer_K_u_factor(params.get("layer_K_u_factor")),
        spacer_after_layer=None if _missing(spacer) else int(spacer),
        interlayer_coupling_J_m2=0.0 if _missing(interlayer_J) else float(interlayer_J),
    )


def field_grid(cfg: dict) -> np.ndarray:
    f = cfg["field"]
    return np.linspace(-f["B_max_T"], f["B_max_T"], f["n_fields"])


def hysteresis_area(fields_T: np.ndarray, descending: np.ndarray) -> float:
    """Area (T) between the descending branch and the ascending one, m_asc(H) = −m_desc(−H)."""
    ascending = -descending[::-1]
    return float(np.trapezoid(descending - ascending, fields_T))


def screen(cfg: dict, params: dict, sample_id: int) -> dict:
    """Saturate, sweep half the major loop, and decide: saturated at ±B_max and hysteretic enough."""
    start = time.perf_counter()
    row = {"sample_id": sample_id, "screen_status": "failed", "screen_reason": "", "hysteresis_area_T": np.nan,
           "mz_at_max": np.nan, "mz_at_min": np.nan, "screen_s": np.nan}
    try:
        film, m0, disorder = build_film(cfg, params, sample_id)
        fields = field_grid(cfg)
        sc = cfg["screening"]
        descending, states, _ = descending_branch(film, m0, fields, cfg["minimizer"]["torque_tol_T"],
                                                  cfg["minimizer"]["max_iterations"], keep_states=(0, -1))
        free = ~disorder.pinning_mask
        mz_max = float(states[len(fields) - 1][2][free].mean())
        mz_min = float(states[0][2][free].mean())
        area = hysteresis_area(fields, descending)
        row.update(hysteresis_area_T=area, mz_at_max=mz_max, mz_at_min=mz_min)
        if mz_max < sc["saturation_mz"]:
            row.update(screen_status="rejected", screen_reason=f"not saturated at +B_max (m_z={mz_max:.3f})")
        elif mz_min > -sc["saturation_mz"]:
            row.update(screen_status="rejected", screen_reason=f"does not reverse to saturation at -B_max (m_z={mz_min:.3f})")
        elif area < sc["min_hysteresis_area_T"]:
            row.update(screen_status="rejected", screen_reason=f"hysteresis area {area:.4f} T below {sc['min_hysteresis_area_T']} T")
        else:
            row.update(screen_status="passed", screen_reason="")
    except Exception as error:  # recorded, never fatal for the chunk
        row.update(screen_status="failed", screen_reason=f"{type(error).__name__}: {error}")
        row["traceback"] = traceback.format_exc(limit=3)
    row["screen_s"] = time.perf_counter() - start
    return row


def simulate(cfg: dict, params: dict, sample_id: int) -> dict:
    """The FORC family of one sample (quasi-static protocol) and its image."""
    start = time.perf_counter()
    out = {"sample_id": sample_id, "status": "failed", "reason": "", "image": None, "curves_mz": None,
           "descending_mz": None, "family_s": np.nan, "relaxations": 0, "unconverged": 0}
    try:
        protocol = cfg["protocol"]["name"]
        if protocol == "llg":
            film, m0, _ = build_film(cfg, params, sample_id, pinning="slaved")
            p = cfg["protocol"]
            settings = SlewRate(alpha=p["alpha"], safety=p["safety"], rate_min_T_per_s=p["rate_min_T_per_s"],
                                rate_max_T_per_s=p["rate_max_T_per_s"])
            fam = adaptive_family(film, m0, n_fields=cfg["field"]["n_fields"], B_max_T=cfg["field"]["B_max_T"],
                                  settings=settings)
            fam.stats.setdefault("relaxations", 0)
            fam.stats.setdefault("unconverged", 0)
        else:
            film, m0, _ = build_film(cfg, params, sample_id)
            fam = quasistatic_family(film, m0, n_fields=cfg["field"]["n_fields"], B_max_T=cfg["field"]["B_max_T"],
                                     torque_tol_T=cfg["minimizer"]["torque_tol_T"],
                                     max_iterations=cfg["minimizer"]["max_iterations"])
        out.update(status="ok", image=rasterize_grid_family(fam.curves_mz), curves_mz=fam.curves_mz,
                   descending_mz=fam.descending_mz, relaxations=fam.stats["relaxations"],
                   unconverged=fam.stats["unconverged"], raw_curves=getattr(fam, "raw_curves", None))
        if fam.stats["unconverged"]:
            out["reason"] = f"{fam.stats['unconverged']} relaxations hit max_iterations"
    except Exception as error:
        out.update(status="failed", reason=f"{type(error).__name__}: {error}")
    out["family_s"] = time.perf_counter() - start
    return out
