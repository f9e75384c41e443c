"""How many patches a file averages (loop.patches), checked on hysteron ensembles whose step heights are
known in closed form, and the realisation floor drawn at it: on an effect-free film of few patches the
loop's default path names no effect (issue 59)."""

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from forcdecode.loop.patches import PATCH_CHOICES, estimate_patches, null_films, step_height
from forcdecode.loop.refit import realisation_floor

N = 48
FIELDS = np.linspace(-1, 1, N)
ROOT = Path(__file__).resolve().parents[2]


def hysteron_family(up_T: float, down_T: float) -> np.ndarray:
    """The grid FORC family of one square hysteron (a patch that reverses in one jump): it switches down
    on the descending branch at -down_T and up on an ascending curve at up_T (rows H_r, columns H)."""
    HR, H = np.meshgrid(FIELDS, FIELDS, indexing="ij")
    start = np.where(HR > -down_T, 1.0, -1.0)
    m = np.where((start > 0) | (H >= up_T), 1.0, -1.0)
    return np.where(H >= HR, m, np.nan)


def patches(count: int, rng) -> list[np.ndarray]:
    return [hysteron_family(*rng.normal(0.4, 0.12, size=2).clip(0.05, 0.95)) for _ in range(count)]


def test_step_height_is_the_jump_of_one_patch_and_two_over_P_for_P_patches_apart():
    """Closed form: a curve that reverses in one jump of 2 gives Σ Δm²/Σ|Δm| = 4/2 = 2 exactly; P patches
    whose switching fields fall in different grid intervals give jumps of 2/P, so exactly 2/P."""
    assert step_height(hysteron_family(0.4, 0.3)) == pytest.approx(2.0, abs=1e-12)
    for p in (2, 3, 5):
        spaced = np.mean([hysteron_family(0.1 + 0.17 * k, 0.12 + 0.16 * k) for k in range(p)], axis=0)
        assert step_height(spaced) == pytest.approx(2.0 / p, abs=1e-12)
    assert step_height(np.full((4, 4), np.nan)) == 0.0


@pytest.mark.parametrize("true_patches", [1, 2, 8])
def test_the_estimate_is_consistent_with_the_true_patch_number_and_its_floor_never_above_it(true_patches):
    """A file averaging P hysterons (another draw than the pool's, noise 0.002) against a pool of 16
    single hysterons of the same switching-field distribution: P lies in the consistent set and the floor
    is drawn at or below it (the conservative side); one patch is never read as many."""
    rng = np.random.default_rng(100 + true_patches)
    noise = 0.002
    measured = np.mean(patches(true_patches, rng), axis=0) + noise * rng.normal(size=(N, N))
    pool = patches(16, np.random.default_rng(7))
    estimate = estimate_patches(measured, pool, noise_sigma=noise, seed=3)
    assert true_patches in estimate.consistent, estimate.report()
    assert estimate.floor_patches <= true_patches
    if true_patches == 1:
        assert estimate.estimate == 1 and estimate.floor_patches == 1
    report = estimate.report()
    assert set(report["by_patches"]) == {str(p) for p in PATCH_CHOICES} and report["estimate"] == estimate.label()


def test_a_smooth_file_is_read_as_many_patches_and_its_floor_drawn_at_eight():
    rng = np.random.default_rng(5)
    measured = np.mean(patches(400, rng), axis=0)
    estimate = estimate_patches(measured, patches(16, np.random.default_rng(8)), noise_sigma=0.001, seed=3)
    assert estimate.estimate is None and estimate.label() == "more than 8"
    assert estimate.floor_patches == 8 and estimate.consistent == ()


def test_null_films_average_the_asked_number_of_singles_disjoint_where_the_pool_allows():
    pool = [np.eye(16)[k] for k in range(16)]  # single k marks index k: a film's support says which it averaged
    films = null_films(pool, 2, count=6, seed=1)
    supports = [set(np.flatnonzero(f)) for f in films]
    assert len(films) == 6 and all(len(s) == 2 for s in supports)
    assert len(set().union(*supports)) == 12  # disjoint: 6 pairs of 12 different singles
    assert all(np.allclose(f[f > 0], 0.5) for f in films)
    overlapping = null_films(pool, 8, count=6, seed=1)
    assert all(len(set(np.flatnonzero(f))) == 8 for f in overlapping)
    assert [f.tolist() for f in null_films(pool, 8, count=6, seed=1)] == [f.tolist() for f in overlapping]
    with pytest.raises(ValueError):
        null_films(pool, 17)


def test_the_realisation_floor_from_P_patch_null_films_is_unbiased():
    """Synthetic realisations of variance v: null films are P-averages, the base an n-average; the pooled
    estimate recovers v within 5 % (E[(pseudo − base)²] = v (1/P + 1/n))."""
    rng = np.random.default_rng(0)
    v, n, P = 0.04, 2, 8
    shape = (40, 40)
    base = np.sqrt(v / n) * rng.normal(size=shape)
    squares = [(np.sqrt(v / P) * rng.normal(size=shape) - base) ** 2 for _ in range(400)]
    spread = np.full(shape, v)
    floor = realisation_floor(spread, n, squares, null_patches=P)
    assert float(np.mean(floor)) == pytest.approx(v, rel=0.05)


def test_a_two_patch_pinned_film_with_its_true_hamiltonian_gets_no_effect(tmp_path):
    """The issue's control, on our engine: a pinned, exchange-coupled perpendicular film averaged over two
    disorder realisations (key "sample", not the loop's own), 0.3 % noise, no effect, decoded with its
    true Hamiltonian by the default command. Before the floor the default path named thermal activation
    on such films; now the verdict is "none" or ambiguous with realisation noise, the file's patch
    number is estimated and every candidate's floor is printed beside it."""
    from forcdecode.cli import main
    from forcdecode.infer.resimulate import resimulate
    from forcdecode.loop.command import load_config
    from forcdecode.loop.effects import NO_EFFECT_MEMBERS
    from forcdecode.measured.writers import write_micromag_0015
    from forcdecode.micromag.build import mesh_from_config

    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    n = cfg["field"]["n_fields"] = 24
    config_path = tmp_path / "cfg.yaml"
    config_path.write_text(yaml.safe_dump(cfg))
    params = {"Ms": 8e5, "A_ex": 1.3e-11, "K_u": 8e5, "D": 1e-3, "N_pin": 2, "sigma_theta_deg": 3.0, "sigma_K": 0.1}
    (tmp_path / "params.json").write_text(json.dumps(params))
    truth = resimulate(load_config(config_path), params, n_profiles=2, key="sample")
    mesh = mesh_from_config(cfg)
    scale = params["Ms"] * mesh.n_cells * mesh.cell_volume
    fields = np.linspace(-1, 1, n)
    rng = np.random.default_rng(0)
    curves = [(fields[i:], (truth[i, i:] + 0.003 * rng.normal(size=n - i)) * scale) for i in range(n)]
    path = write_micromag_0015(tmp_path / "control.frc", fields, curves)
    out = tmp_path / "loop"
    code = main(["loop", str(path), "--out", str(out), "--params", str(tmp_path / "params.json"),
                 "--config", str(config_path), "--profiles", "4", "--every-k", "3", "--force",
                 "--no-measured-protocol"])
    assert code == 0
    report = json.loads((out / "report.json").read_text())
    analysis = report["analysis"]
    assert report["verdict"] in ("none", "unexplained structured residual", "ambiguous"), report["verdict_text"]
    if report["verdict"] == "ambiguous":
        assert set(analysis["ambiguous"]) & NO_EFFECT_MEMBERS, report["verdict_text"]
    assert report["patches"]["floor_patches"] <= 2
    floors = [c for name, c in analysis["candidates"].items() if name != "none"]
    assert floors and all("null_gain" in c for c in floors)
    text = (out / "report.md").read_text()
    assert "patches" in text and "(floor)" in text


def test_singles_that_do_not_saturate_in_the_window_stand_in_as_grid_families_of_their_own_disorder(tmp_path):
    """A file measured in a window (±0.3 T) narrower than its film's switching (a hard film, K_u 1.2
    MJ/m³): a single of the pool that does not saturate there is replaced by the grid family of the same
    disorder (key, k), in order, simulated on the workers as the rest (``fallbacks`` counts them)."""
    from forcdecode.infer.resimulate import grid_single
    from forcdecode.loop.patches import rasterized_singles
    from forcdecode.measured.reader import read_forc
    from forcdecode.measured.writers import write_micromag_0015

    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    params = {"Ms": 6e5, "A_ex": 1e-11, "K_u": 1.2e6, "D": 0.0, "N_pin": 0, "sigma_theta_deg": 2.0, "sigma_K": 0.05}
    reversal = np.linspace(-0.3, 0.3, 6)
    curves = [(np.linspace(h, 0.3, 4), np.ones(4) * 1e-9) for h in reversal]
    path = write_micromag_0015(tmp_path / "narrow.frc", reversal, curves, calibration_moments_Am2=np.ones(6) * 1e-9,
                               calibration_field_T=0.3)
    data = read_forc(path)
    pool = rasterized_singles(cfg, params, data, 1e-9, 0.0, count=3, key="loop_null", max_step_T=0.02)
    assert len(pool) == 3 and pool.fallbacks >= 2
    # the stand-ins are the grid families of their own k (in order); the others are the file's protocol put
    # on the grid, which differ from any grid family
    same = [np.array_equal(single, grid_single(cfg, params, "loop_null", k), equal_nan=True) for k, single in enumerate(pool)]
    assert sum(same) == pool.fallbacks
    assert pool.protocol["singles"] == 3  # a probe saturated: every single swept on the file's protocol
    # a film that switches nowhere in the window (K_u 5 MJ/m³): no probe saturates, and the rest go to the
    # grid without the protocol's sweep
    hard = rasterized_singles(cfg, {**params, "K_u": 5e6}, data, 1e-9, 0.0, count=3, key="loop_null", max_step_T=0.02)
    assert hard.fallbacks == 3 and hard.protocol["singles"] == 2
    assert all(np.array_equal(single, grid_single(cfg, {**params, "K_u": 5e6}, "loop_null", k), equal_nan=True)
               for k, single in enumerate(hard))
    assert not np.array_equal(pool[0], pool[1], equal_nan=True)  # each its own disorder


def test_the_pool_keeps_its_simulation_of_the_files_protocol(tmp_path):
    """The patch pool simulated on the file's own protocol keeps that simulation (``on_protocol``): per curve the
    mean over its singles at the file's points, exactly what re-simulating the protocol with the pool's disorder
    stream and sweep step gives (``resimulate_measured``), so the report's residual at the measured points
    need not simulate it again; and ``measured_points_residual`` given it simulates nothing and reproduces
    the re-simulated residual."""
    from forcdecode.infer.resimulate import resimulate_measured
    from forcdecode.loop.measured_loop import measured_points_residual
    from forcdecode.loop.patches import rasterized_singles
    from forcdecode.measured.reader import read_forc
    from forcdecode.forc.saturation import domain_of_measurement
    from forcdecode.measured.writers import write_micromag_0015

    cfg = yaml.safe_load((ROOT / "config" / "test.yaml").read_text())
    params = {"Ms": 6e5, "A_ex": 1e-11, "K_u": 3e5, "D": 0.0, "N_pin": 0, "sigma_theta_deg": 2.0, "sigma_K": 0.05}
    reversal = np.linspace(-0.8, 0.8, 10)
    curves = [(np.linspace(h, 0.8, 12), np.ones(12) * 1e-9) for h in reversal]
    path = write_micromag_0015(tmp_path / "film.frc", reversal, curves, calibration_moments_Am2=np.ones(10) * 1e-9,
                               calibration_field_T=0.8)
    data = read_forc(path)
    pool = rasterized_singles(cfg, params, data, 1e-9, 0.0, count=3, key="loop_null", max_step_T=0.02)
    assert pool.fallbacks == 0  # every single saturates in the window: all swept on the file's protocol
    assert pool.protocol == {"params": params, "max_step_T": 0.02, "singles": 3}
    reversal = [float(c.reversal_field_T) for c in data.curves]  # the file's order and values
    fields = [np.concatenate([[h], np.asarray(c.field_T, float)[1:]]) for h, c in zip(reversal, data.curves)]
    again = resimulate_measured(cfg, params, reversal, fields, n_profiles=3, key="loop_null", max_step_T=0.02)
    assert len(pool.on_protocol) == len(again) == 10
    for kept, simulated in zip(pool.on_protocol, again):
        np.testing.assert_allclose(kept, simulated, rtol=0, atol=1e-12)
    assert np.ptp(np.concatenate(again)) > 1.0  # the film reverses inside the window: a test that can fail
    # a file holding exactly that simulation: the residual at its points, given the pool's, is nil
    exact = write_micromag_0015(tmp_path / "exact.frc", reversal, [(f, 1e-9 * m) for f, m in zip(fields, again)],
                                calibration_moments_Am2=np.full(10, 1e-9 * max(v[-1] for v in again)), calibration_field_T=0.8)
    exact_data = read_forc(exact)
    domain = domain_of_measurement(exact_data, cfg["field"]["B_max_T"], cfg["field"]["n_fields"])
    given = measured_points_residual(cfg, params, exact_data, domain, n_profiles=3, max_step_T=0.02,
                                     simulated=pool.on_protocol)
    assert given["n_profiles"] == 3 and given["n_points"] == sum(len(c) for c in data.curves)
    assert given["rms_Am2"] < 1e-6 * domain.moment_saturation_Am2
    with pytest.raises(ValueError, match="one value per measured point"):
        measured_points_residual(cfg, params, exact_data, domain, simulated=pool.on_protocol[:-1])
