"""Our FORC distributions against PmagPy 4.5.2's FORC module (``pmagpy.forc``; its LOESS agrees
with FORCsensei to ~1e-11 of the peak) on the real measured files of ``../shared/data/measured``.

Agreement is stated as max |Δρ| / max |ρ| over the nodes where both give a value, and the sets of
nodes where each gives a value (NaN masks) must be equal.

Conventions, and how each difference is bridged here:

* Axes. PmagPy's module docstring calls H_b the reversal field and H_a the applied field, but its
  code uses Pike et al.'s own labels the other way round: ``build_forc_grid``,
  ``loess_rho_from_grid_fast`` and ``variforc_rho_from_grid`` take ``Ha_vals`` = reversal fields
  (rows) and ``Hb_vals`` = applied fields (columns, H ≥ H_r), ``M_grid[i, j]`` = M(H_r = Ha_vals[i],
  H = Hb_vals[j]). That is exactly our ``curves[i, j]`` on (``reversal_fields_T``, ``fields_T``),
  so the arrays are passed as they are (we name axes by role, never a/b).
* Sign and measure. Both compute ρ = −½ ∂²M/∂H_r∂H (> 0 for a hysteron ensemble), a density per
  unit H_r·H; PmagPy's B_c = (H − H_r)/2, B_u = (H + H_r)/2 are our H_c, H_u.
* Units. PmagPy works in T and A m² (ρ in A m²/T²); ``measured_grid`` normalizes the moments by
  their largest |M| (ρ in 1/T²). ρ is linear in M, so PmagPy's grid is divided by the same number.
* Smoothing factor. Our ``kernel="loess"`` is PmagPy's LOESS: tricube weights (1 − u³)³ on the
  ellipse u ≤ 1 in grid-index offsets, the rim u = 1 counting as neighbours with weight 0, a
  quadratic in coordinates scaled by the median steps, ρ from the mixed coefficient. PmagPy takes
  the semi-axes in tesla and rounds them up to whole steps (⌈span/ΔH⌉, ΔH the median step of each
  axis); our SF is that number of steps, so PmagPy gets span = (SF − ½)·ΔH. ``min_points`` is
  passed to both. Our default ``kernel="pike"`` (equal weights on the (2SF + 1)² square, Pike et
  al. 1999) is a different smoother: at SF = 3 it differs from the LOESS by 60–90 % of the peak on
  these noisy files (edge and noise nodes), so the comparison uses ``kernel="loess"``.
* Edges. Both use only points with H ≥ H_r, need ``min_points`` neighbours and a 6×6 normal matrix
  of full rank (σ_min > 6 ε σ_max, ``np.linalg.matrix_rank``'s criterion); hence equal masks.
* Drift. PmagPy subtracts the calibration drift (additive, interpolated between the calibration
  points around each curve); ours scales by the curve's own calibration point (multiplicative, as
  FORCsensei). With each tool's own correction the diagrams differ by 3–8 % of the peak (MD00-2361
  8.3 %, UB199BF 5.2 %, MSM33-55-1 2.9 %, agm_cgs 5.5 %), all from the correction: end to end
  (each tool's reader and gridding) the comparison is therefore made on the raw moments, and the
  estimators alone on one drift-corrected grid.
* Readers. Both readers give the same (H, M) numbers, bit for bit (the cgs file converted alike).
  PmagPy drops the one-point curve that MicroMag files start with (reversal at the top field);
  ours keeps it, and it gives no grid point. PmagPy's multi-segment reader appends the file's final
  return-to-zero segment to the last curve of ``MSM33-53-1-d400_5.irforc`` (two extra points, one
  at −1.6 mT), and it cannot read the Lake Shore CSV (no ``HCal`` header), so those two files are
  compared at the estimator level only.

Measured (``pytest tests/forc/test_pmagpy_reference.py -s -m "slow or not slow"`` prints every
figure): end to end ≤ 4.6e-12; LOESS on our grids ≤ 3.7e-12 (all six full files); VARIFORC ≤ 1.5e-12
against PmagPy's NumPy engine and 0 (bit-identical) against its compiled one on whole files.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

pmag_forc = pytest.importorskip("pmagpy.forc", reason="PmagPy not installed: pip install -e .[reference]")

from forcdecode.forc.diagram import Variforc, forc_distribution, variforc_distribution  # noqa: E402
from forcdecode.forc.render import measured_grid  # noqa: E402
from forcdecode.measured import read_forc  # noqa: E402

pytestmark = pytest.mark.reference

DATA_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "measured"
MICROMAG = ["MD00-2361.frc", "UB199BF.frc", "MSM33-55-1_d330.forc", "agm_cgs_0141327c.frc"]
ALL_FULL = MICROMAG + ["MSM33-53-1-d400_5.irforc", "B-9-3-85-87-FORC-1.5T.csv"]
TOLERANCE = 1e-6


def data_file(name: str) -> Path:
    path = DATA_DIR / name
    if not path.is_file():
        message = f"measured file {path} is absent"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message)
        pytest.skip(message)
    return path


@lru_cache(maxsize=None)
def our_grid(name: str, drift_correction: bool):
    measurement = read_forc(data_file(name), drift_correction=drift_correction)
    scale = max(np.abs(c.moment_Am2).max() for c in measurement.curves)
    return measurement, scale, measured_grid(measurement)


@lru_cache(maxsize=None)
def pmagpy_forcs(name: str):
    """PmagPy's curves of a regular MicroMag file, raw (its reader, no drift correction)."""
    path = data_file(name)
    tags, start = pmag_forc.read_header_tags_and_data_start(path)
    hcal = float(tags["HCal"])
    raw = pmag_forc.read_segments_raw(path, data_start_idx=start, HCal=hcal, verbose=False)
    segments = pmag_forc.split_cal_first_point(raw, HCal=hcal)
    return ([s for s in segments if s.kind == "forc"], [s for s in segments if s.kind == "cal"])


def pmagpy_loess(reversal, fields, m, sf: int, min_points: int):
    step_h, step_r = np.median(np.diff(fields)), np.median(np.diff(reversal))
    return pmag_forc.loess_rho_from_grid_fast(reversal, fields, m, span_Hb_T=(sf - 0.5) * step_h,
                                              span_Ha_T=(sf - 0.5) * step_r, min_pts=min_points)


def agreement(ours: np.ndarray, theirs: np.ndarray) -> float:
    """max |Δρ| / max |ρ| where both are finite, after checking that the NaN masks are equal
    (printed: ``pytest -s`` or ``-rP`` shows the figure of every case)."""
    assert np.array_equal(np.isfinite(ours), np.isfinite(theirs)), "different nodes were fitted"
    both = np.isfinite(ours)
    assert both.sum() > 1000
    value = float(np.abs(ours - theirs)[both].max() / np.abs(theirs[both]).max())
    print(f"{os.environ.get('PYTEST_CURRENT_TEST', '').split(' ')[0]}: {both.sum()} nodes, "
          f"max|Δρ|/max|ρ| = {value:.2e}")
    return value


@pytest.mark.parametrize("name", MICROMAG)
def test_readers_give_the_same_numbers(name):
    forcs, calibration = pmagpy_forcs(name)
    measurement, _, _ = our_grid(name, False)
    theirs = {s.Ha: s for s in forcs}
    matched = 0
    for curve in measurement.curves:
        other = theirs.get(float(curve.field_T.min()))
        if other is None:
            assert len(curve) == 1  # the one-point top curve PmagPy leaves out
            continue
        matched += 1
        np.testing.assert_array_equal(other.H, curve.field_T)
        np.testing.assert_array_equal(other.M, curve.moment_Am2)
    assert matched == len(forcs) == len(measurement.curves) - 1
    np.testing.assert_array_equal([s.M[0] for s in calibration],
                                  [point.moment_Am2 for point in measurement.calibration])


@pytest.mark.parametrize("name", MICROMAG)
def test_end_to_end_without_drift_correction(name):
    """Each tool reads and grids the file its own way; the same lattice comes out and LOESS ρ at
    SF = 3 agrees."""
    forcs, _ = pmagpy_forcs(name)
    reversal, fields, m_grid, _, _ = pmag_forc.build_forc_grid(forcs, verbose=False)
    _, scale, (hr, h, m) = our_grid(name, False)
    np.testing.assert_array_equal(h, fields)
    rows = np.searchsorted(hr, reversal)
    np.testing.assert_array_equal(hr[rows], reversal)
    assert np.isnan(np.delete(m, rows, axis=0)).all()  # our extra row is the one-point curve
    np.testing.assert_allclose(m[rows], m_grid / scale, rtol=0, atol=1e-15)
    ours = forc_distribution(hr, h, m, 3, 10, kernel="loess").rho[rows]
    assert agreement(ours, pmagpy_loess(reversal, fields, m_grid / scale, 3, 10)) < TOLERANCE


@pytest.mark.parametrize("name,sf", [(name, 3) for name in ALL_FULL] + [("UB199BF.frc", 5)])
def test_loess_estimator_on_our_drift_corrected_grid(name, sf):
    _, _, (hr, h, m) = our_grid(name, True)
    ours = forc_distribution(hr, h, m, sf, 10, kernel="loess").rho
    assert agreement(ours, pmagpy_loess(hr, h, m, sf, 10)) < TOLERANCE


PRESETS = {
    "constant": ("regular", dict(smoothing_factor=4, growth_rate=0.0)),
    "regular": ("regular", dict(smoothing_factor=7, growth_rate=0.07)),
    "central_ridge": ("central_ridge", dict(smoothing_factor=9, growth_rate=0.1, central_ridge=4)),
}


def variforc_pair(preset: str):
    kind, options = PRESETS[preset]
    settings = pmag_forc.variforc_settings(kind, **options)
    ours = Variforc(sc0=settings["sc0"], sc1=settings["sc1"], su0=settings["sb0"], su1=settings["sb1"],
                    lambda_c=settings["lambda_c"], lambda_u=settings["lambda_b"])
    return ours, settings


@pytest.mark.parametrize("preset", sorted(PRESETS))
@pytest.mark.parametrize("name", ["UB199BF.frc", "MSM33-55-1_d330.forc"])
def test_variforc_matches_pmagpy(name, preset):
    """PmagPy's NumPy engine (batched normal equations) on a window of a real grid around the
    central ridge: the 40 curves reversed just below 0 T, 80 fields from the lowest of them up
    (the engine takes ~15 s on a whole file)."""
    ours_settings, settings = variforc_pair(preset)
    _, _, (hr, h, m) = our_grid(name, True)
    i0 = np.searchsorted(hr, 0.0) - 40
    j0 = np.searchsorted(h, hr[i0])
    hr, h, m = hr[i0:i0 + 40], h[j0:j0 + 80], m[i0:i0 + 40, j0:j0 + 80]
    ours = variforc_distribution(hr, h, m, ours_settings).rho
    theirs = pmag_forc.variforc_rho_from_grid(hr, h, m, **settings, engine="numpy")
    assert agreement(ours, theirs) < TOLERANCE


@pytest.mark.slow
@pytest.mark.parametrize("name", ["UB199BF.frc", "MSM33-55-1_d330.forc"])
def test_variforc_matches_pmagpys_compiled_engine_on_whole_files(name):
    """Whole files against PmagPy's numba engine (its compilation takes ~30 s per session)."""
    for preset in sorted(PRESETS):
        ours_settings, settings = variforc_pair(preset)
        _, _, (hr, h, m) = our_grid(name, True)
        ours = variforc_distribution(hr, h, m, ours_settings).rho
        theirs = pmag_forc.variforc_rho_from_grid(hr, h, m, **settings, engine="numba")
        assert agreement(ours, theirs) < TOLERANCE
