"""Per-sample simulation: build the film from its parameters (``micromag.build``), screen it,
simulate its FORC family.

Failures are results: a sample whose simulation diverges (non-finite magnetization) or raises is
recorded with status "failed" and the reason; it never stops the chunk.
"""

from __future__ import annotations

import time
import traceback

import numpy as np

from ..config import realisations
from ..core.streams import stream_rng
from ..forc.protocol import descending_branch
from ..forc.raster import fill_below_reversal, rasterize_grid_family
from ..forc.simulate import simulate_family
from ..micromag.build import REFERENCE_CELLS, build_film, mesh_from_config, pinning_cells, sweep_options

__all__ = ["REFERENCE_CELLS", "build_film", "mesh_from_config", "pinning_cells", "field_grid", "hysteresis_area",
           "screen", "simulate", "simulate_realisation", "realisation_rng"]  # the first four live in micromag.build (re-exported for old callers)


def field_grid(cfg: dict) -> np.ndarray:
    f = cfg["field"]
    return np.linspace(-f["B_max_T"], f["B_max_T"], f["n_fields"])


def hysteresis_area(fields_T: np.ndarray, descending: np.ndarray) -> float:
    """Area (T) between the descending branch and the ascending one, m_asc(H) = −m_desc(−H)."""
    ascending = -descending[::-1]
    return float(np.trapezoid(descending - ascending, fields_T))


def screen(cfg: dict, params: dict, sample_id: int) -> dict:
    """Saturate, sweep half the major loop, and decide: saturated at ±B_max and hysteretic enough.

    One disorder realisation (the sample's ``disorder`` stream, realisation 0) whatever
    ``realisations`` says: screening decides whether a Hamiltonian is worth a family, and with R = 1
    it must stay what it was; ``simulate`` averages the R realisations."""
    start, cpu_start = time.perf_counter(), time.process_time()  # wall and this process's CPU (s)
    row = {"sample_id": sample_id, "screen_status": "failed", "screen_reason": "", "hysteresis_area_T": np.nan,
           "mz_at_max": np.nan, "mz_at_min": np.nan, "screen_s": np.nan, "screen_cpu_s": np.nan}
    try:
        film, m0, disorder = build_film(cfg, params, sample_id)
        fields = field_grid(cfg)
        sc = cfg["screening"]
        opts = sweep_options(cfg)
        descending, states, _ = descending_branch(film, m0, fields, opts["torque_tol_T"], opts["max_iterations"],
                                                  keep_states=(0, -1), extrapolate=opts["extrapolate"],
                                                  warm_step=opts["warm_step"])
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
    row["screen_cpu_s"] = time.process_time() - cpu_start
    return row


def realisation_rng(cfg: dict, sample_id: int, realisation: int):
    """The disorder generator of realisation ``realisation`` of sample ``sample_id``: None for 0
    (``build_film`` then draws from the sample's ``disorder`` stream, as a single-realisation dataset
    always did), the ``disorder_realisation`` stream of (sample id, r) for r ≥ 1."""
    if realisation == 0:
        return None
    return stream_rng(cfg["seed"], "disorder_realisation", int(sample_id), int(realisation))


def simulate_realisation(cfg: dict, params: dict, sample_id: int, realisation: int = 0):
    """The FORC family (``ForcFamily``) of one disorder realisation of the sample (config's protocol)."""
    return simulate_family(cfg, params, sample_id, rng=realisation_rng(cfg, sample_id, realisation))


def simulate(cfg: dict, params: dict, sample_id: int) -> dict:
    """The FORC family of one sample and its image: with ``realisations: R`` (default 1) the mean
    ⟨m_z⟩ family over R disorder realisations (``realisation_rng``; the same field protocol each),
    the image rasterized from that mean exactly as a single family's. ``curves_std_mz`` is the
    spread: the standard deviation (ddof 0) of the R families' curves, zero for R = 1 (NaN where the
    curves are, below the diagonal). ``family_s``/``family_cpu_s`` cover all R realisations.

    A realisation that raises or leaves a missing value on or above the diagonal fails the sample
    (status "failed", the realisation named in the reason): a mean over fewer realisations would
    be another kind of sample. Unconverged relaxations are summed over the realisations and named
    in the reason, as for one family. R = 1 is the single family of before, bit for bit."""
    start, cpu_start = time.perf_counter(), time.process_time()
    count = realisations(cfg)
    out = {"sample_id": sample_id, "status": "failed", "reason": "", "image": None, "curves_mz": None,
           "descending_mz": None, "curves_std_mz": None, "realisations": count, "family_s": np.nan,
           "family_cpu_s": np.nan, "relaxations": 0, "unconverged": 0}
    try:
        if count == 1:
            fam = simulate_realisation(cfg, params, sample_id)
            out.update(status="ok", image=rasterize_grid_family(fam.curves_mz), curves_mz=fam.curves_mz,
                       descending_mz=fam.descending_mz, curves_std_mz=np.where(np.isnan(fam.curves_mz), np.nan, 0.0),
                       relaxations=fam.stats["relaxations"], unconverged=fam.stats["unconverged"],
                       raw_curves=getattr(fam, "raw_curves", None))
            if fam.stats["unconverged"]:
                out["reason"] = f"{fam.stats['unconverged']} relaxations hit max_iterations"
        else:
            families = []
            for r in range(count):
                try:
                    fam = simulate_realisation(cfg, params, sample_id, r)
                    fill_below_reversal(fam.curves_mz)  # ValueError on a missing value above the diagonal
                except Exception as error:
                    raise RealisationFailed(f"realisation {r} of {count}: {type(error).__name__}: {error}") from error
                families.append(fam)
            curves = np.stack([f.curves_mz for f in families])
            mean = curves.mean(axis=0)
            unconverged = [int(f.stats["unconverged"]) for f in families]
            out.update(status="ok", image=rasterize_grid_family(mean), curves_mz=mean,
                       descending_mz=np.stack([f.descending_mz for f in families]).mean(axis=0),
                       curves_std_mz=curves.std(axis=0), relaxations=sum(int(f.stats["relaxations"]) for f in families),
                       unconverged=sum(unconverged))
            raw = [getattr(f, "raw_curves", None) for f in families]
            if any(r is not None for r in raw):
                out["raw_realisations"] = raw
            if sum(unconverged):
                out["reason"] = (f"{sum(unconverged)} relaxations hit max_iterations ("
                                 + ", ".join(f"realisation {r}: {n}" for r, n in enumerate(unconverged) if n) + ")")
    except RealisationFailed as error:
        out.update(status="failed", reason=str(error))
    except Exception as error:
        out.update(status="failed", reason=f"{type(error).__name__}: {error}")
    out["family_s"] = time.perf_counter() - start
    out["family_cpu_s"] = time.process_time() - cpu_start
    return out


class RealisationFailed(RuntimeError):
    """One disorder realisation of a sample failed (the message names it)."""
