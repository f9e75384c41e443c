"""bench information (issue 43): the Fisher core against a case known in closed form, a
non-interacting ensemble of square hysterons through the FORC protocol (bench/information_check.py)."""

import numpy as np
import pytest

from forcdecode.bench import information_check as check
from forcdecode.bench.information import (QUANT_STEP, compressed_fisher, crb, fisher_by_simulation,
                                          fisher_from_families, ledoit_wolf, principal_angle_deg, stencil,
                                          upper_triangle)

U = np.array([0.4, 0.5, 0.5])  # h0 = 0.35 T, s = 0.3; the third parameter does not enter
N_PARTICLES, NOISE_SD, N_FIELDS, R, DELTA = 200, 0.02, 12, 1000, 0.05
TOLERANCE = 0.10
"""Bench vs analytic Cramér–Rao bound, relative. At R = 1000 realisations of p = 78 points the
sample-covariance bias (≈ n/(n − p), Hartlap) alone is ≈ 4 % on a bound; a factor-2 error in the
step or a lost common-random-number pairing moves a bound by ≥ 2× or the inert bound below 1."""


@pytest.fixture(scope="module")
def bench():
    f = check.simulator(N_PARTICLES, NOISE_SD, n_fields=N_FIELDS)
    return f, fisher_by_simulation(f, U, check.NAMES, DELTA, range(R))


@pytest.fixture(scope="module")
def analytic_crb():
    F = check.analytic_fisher(U, N_PARTICLES, NOISE_SD, n_fields=N_FIELDS)
    assert np.allclose(F[2], 0) and np.allclose(F[:, 2], 0)  # the inert parameter carries nothing
    return crb(F[:2, :2])


def test_bench_fisher_matches_closed_form(bench, analytic_crb):
    _, res = bench
    ratio = res.crb_single[:2] / analytic_crb
    assert np.all(np.abs(ratio - 1) < TOLERANCE), (ratio, res.crb_single, analytic_crb)
    assert np.allclose(res.crb_mean_R[:2], res.crb_single[:2] / np.sqrt(R))
    assert np.all(res.noise_fraction[:2] < 0.05)


def test_matched_filter_bound_is_conservative(bench):
    """The matched-filter conditional bound needs no Σ⁻¹ and is never below the true conditional CRB."""
    _, res = bench
    F = check.analytic_fisher(U, N_PARTICLES, NOISE_SD, n_fields=N_FIELDS)
    conditional = 1 / np.sqrt(np.diag(F)[:2])
    matched = np.array(res.extra["crb_conditional_matched"][:2], float)
    assert np.all(matched >= 0.95 * conditional), (matched, conditional)
    assert np.allclose(res.extra["crb_conditional"][:2], conditional, rtol=TOLERANCE)
    assert res.extra["crb_conditional_matched"][2] is None  # ∞: the inert parameter's J is exactly 0


def test_parameter_that_does_not_enter_gets_at_least_the_prior_width(bench):
    _, res = bench
    assert res.crb_single[2] >= 1.0  # ∞ here: F is singular along it (CRN: the differences are exactly 0)
    assert res.crb_mean_R[2] >= 1.0


def test_the_check_fails_on_a_wrong_step(bench, analytic_crb):
    """The same realisations with the step scale wrong by 2: the bounds move by 2, out of tolerance."""
    f, res = bench
    # rebuild the families of the bench run and analyse them with the stencil widths halved
    center = np.stack([f(U, r) for r in range(200)])
    plus, minus, steps = [], [], []
    for i in range(3):
        lo, hi = stencil(U[i], DELTA)
        up, um = U.copy(), U.copy()
        up[i], um[i] = hi, lo
        plus.append(np.stack([f(up, r) for r in range(200)]))
        minus.append(np.stack([f(um, r) for r in range(200)]))
        steps.append(hi - lo)
    wrong = fisher_from_families(center, np.stack(plus), np.stack(minus), np.array(steps) / 2, check.NAMES, U)
    assert np.all(np.abs(wrong.crb_single[:2] / analytic_crb - 1) > TOLERANCE)
    # the compressed (projection) Fisher of the same 200 families, right step: marginal bounds close to exact
    d = (np.stack(plus) - np.stack(minus)) / np.array(steps)[:, None, None]
    compressed = crb(compressed_fisher(center, d, (0, 1)))
    assert np.all(np.abs(compressed / analytic_crb - 1) < 0.15), compressed / analytic_crb


def test_the_check_fails_without_common_random_numbers():
    """u − δ on other realisations than u + δ: the inert parameter's bound drops below the prior's width."""
    f = check.simulator(N_PARTICLES, NOISE_SD, n_fields=N_FIELDS)
    res = fisher_by_simulation(f, U, check.NAMES, DELTA, range(300), crn=False)
    assert res.crb_single[2] < 1.0


def test_ledoit_wolf_formula():
    """Against the textbook expression written densely (scikit-learn is not installed here)."""
    rng = np.random.default_rng(0)
    Y = rng.normal(size=(7, 30)) @ np.diag(np.linspace(0.5, 2, 30))
    s = ledoit_wolf(Y, floor=QUANT_STEP**2 / 12)
    X = Y - Y.mean(0)
    n, p = X.shape
    S = X.T @ X / n
    mu = np.trace(S) / p
    d2 = np.sum((S - mu * np.eye(p)) ** 2) / p
    b2 = sum(np.sum((np.outer(x, x) - S) ** 2) for x in X) / (n**2 * p)
    rho = min(b2, d2) / d2
    dense = rho * mu * np.eye(p) + (1 - rho) * S + QUANT_STEP**2 / 12 * np.eye(p)
    assert np.isclose(s.rho, rho)
    assert np.allclose(s.dense(), dense)
    V = rng.normal(size=(p, 3))
    assert np.allclose(s.solve(V), np.linalg.solve(dense, V))


def test_helpers():
    c = np.arange(16.0).reshape(4, 4)
    assert upper_triangle(c).tolist() == [0, 1, 2, 3, 5, 6, 7, 10, 11, 15]
    assert stencil(0.02, 0.05) == (pytest.approx(1e-4), pytest.approx(0.07))
    assert principal_angle_deg([1, 0], [-1, 0]) == 0.0
    assert np.isclose(principal_angle_deg([1, 0], [1, 1]), 45.0)
    assert np.isinf(crb(np.diag([4.0, 0.0]))[1]) and np.isclose(crb(np.diag([4.0, 0.0]))[0], 0.5)


def test_regimes_and_stratified_fiducials():
    from forcdecode.bench import information_films as info

    base = {"Ms": 4e5, "A_ex": 1e-11, "K_u": 3e5, "D": 1e-3, "N_pin": 10, "sigma_theta_deg": 1.0, "sigma_K": 0.1}
    assert info.regime(base) == "domains" and info.sigma_w(base) > 0
    assert info.regime({**base, "D": 5e-3}) == "spirals"  # 4√(A K_eff) ≈ 3.5 mJ/m² < π·5
    assert info.regime({**base, "Ms": 1e6}) == "K_eff<0" and np.isnan(info.sigma_w({**base, "Ms": 1e6}))
    g = info.gradient(info.sigma_w, base, info.NAMES)
    assert np.isclose(g[info.NAMES.index("D")], -np.pi * 5e-3, rtol=1e-6)  # ∂σ_w/∂u_D = −π (D_hi − D_lo)
    assert g[info.NAMES.index("N_pin")] == 0
    assert np.allclose(info.to_unit(info.from_unit(info.to_unit(base), base)), info.to_unit(base))
    assert info.allot({"K_eff<0": 50, "spirals": 3, "domains": 47}, 16) == {"K_eff<0": 8, "spirals": 1, "domains": 7}
    pool = [{"sample_id": i, "N_pin": (37 * i) % 256, "regime": ("K_eff<0", "domains")[i % 2]} for i in range(40)]
    chosen = info.choose_fiducials(pool, 6)
    assert chosen["allotted"] == {"K_eff<0": 3, "domains": 3}
    picked = chosen["fiducials"]
    assert [p["regime"] for p in picked] == ["K_eff<0", "domains"] * 3  # round-robin: a stopped run stays stratified
    lows = sorted(p["N_pin"] for p in picked if p["regime"] == "domains")
    assert lows[0] < 64 and lows[-1] > 160  # spread over N_pin (the 1/6, 1/2, 5/6 quantiles)


def test_protocol_code_reproduces_the_closed_form_ensemble():
    """The hysteron realisations of the check, run through forc.protocol.quasistatic_family as
    non-interacting Stoner–Wohlfarth cells (0.5° tilt, the laptop's minimizer options), equal the
    closed-form outcome point by point (|Δm| < 2e-3, the cells' tilt) wherever no particle switches
    within 5 mT of a grid field (there the torque tolerance of 1 mT decides, near the saddle-node):
    so the Fisher check above holds for families made by the protocol code, up to that."""
    n = 40
    closed = check.simulator(n, 0.0, n_fields=N_FIELDS)
    low = check.simulator(n, 0.0, n_fields=N_FIELDS, h_shift_T=-5e-3)
    high = check.simulator(n, 0.0, n_fields=N_FIELDS, h_shift_T=5e-3)
    protocol = check.protocol_simulator(n, 0.0, n_fields=N_FIELDS)
    for u, r in ((U, 0), (U + np.array([DELTA, 0, 0]), 0), (U, 1)):
        clear = low(u, r) == high(u, r)
        assert clear.mean() > 0.8
        assert np.max(np.abs(protocol(u, r) - closed(u, r))[clear]) < 2e-3


@pytest.mark.slow
def test_fiducial_processes_run_side_by_side_and_resume(tmp_path, monkeypatch):
    """`bench information --workers 2`: two fiducial processes at once on a tiny film (16 nm box, one
    parameter, R = 2). Both analyses are written, costs.jsonl gets one row per process with its own CPU
    time, and a second call finds everything on disk and simulates nothing; a fiducial whose result was
    removed is re-analysed from its families on disk to the same numbers."""
    import json

    from forcdecode.bench import information_films as info
    from forcdecode.config import load_config, shipped_config

    monkeypatch.setitem(info.FILMS, "tiny", dict(nx=8, ny=8, nz=1, n_grains=2, protocol="quasistatic",
                                                 names=("K_u",)))
    cfg = load_config(shipped_config("config"))
    base = {"Ms": 5.0e5, "A_ex": 1.5e-11, "K_u": 3.5e5, "D": 5e-4, "N_pin": 10, "sigma_theta_deg": 2.0,
            "sigma_K": 0.05}
    fids = [{**base, "sample_id": 1, "regime": "domains"}, {**base, "K_u": 4.0e5, "sample_id": 2, "regime": "domains"}]
    info.run_fiducials(cfg, "tiny", fids, info.FiducialDesign(2, [0.1], 0), tmp_path, say=lambda *_: None, workers=2)
    results = {sid: tmp_path / "tiny" / f"s{sid:05d}.json" for sid in (1, 2)}
    assert all(p.exists() for p in results.values())
    rows = [json.loads(line) for line in (tmp_path / "costs.jsonl").read_text().splitlines()]
    # one process a fiducial, and a freed worker may join the other while it has families unclaimed
    assert {r["sample_id"] for r in rows} == {1, 2} and len(rows) <= 3
    assert all(r["exit"] == 0 and r["cpu_s"] > 0 for r in rows)
    first = json.loads(results[2].read_text())
    n_families = len(list((tmp_path / "tiny").rglob("*.npz")))
    assert n_families == 2 * 3 * 2  # fiducials x (centre, +delta, -delta) x R
    results[2].unlink()
    info.run_fiducials(cfg, "tiny", fids, info.FiducialDesign(2, [0.1], 0), tmp_path, say=lambda *_: None, workers=2)
    again = json.loads(results[2].read_text())
    key = "R2_d0.1"
    assert again["channels"]["float"][key]["crb_single"] == first["channels"]["float"][key]["crb_single"]
    assert len(list((tmp_path / "tiny").rglob("*.npz"))) == n_families


@pytest.mark.slow
def test_workers_beyond_the_fiducials_share_one_fiducial_and_give_its_single_process_result(tmp_path, monkeypatch):
    """One fiducial, two workers: two processes on it, each family simulated once (every family's file
    written by one of them, no claim left), and the analysis equal to that of one process (the families
    are the same draws whoever simulates them). A claim left by a killed run does not block a rerun."""
    import json

    from forcdecode.bench import information_films as info
    from forcdecode.config import load_config, shipped_config

    monkeypatch.setitem(info.FILMS, "tiny", dict(nx=8, ny=8, nz=1, n_grains=2, protocol="quasistatic",
                                                 names=("K_u", "A_ex")))
    cfg = load_config(shipped_config("config"))
    fid = {"Ms": 5.0e5, "A_ex": 1.5e-11, "K_u": 3.5e5, "D": 5e-4, "N_pin": 10, "sigma_theta_deg": 2.0,
           "sigma_K": 0.05, "sample_id": 3, "regime": "domains"}
    shared, alone = tmp_path / "shared", tmp_path / "alone"
    stale = info.claim_path(info.family_path(shared, "tiny", 3, "c", 0))
    stale.parent.mkdir(parents=True)
    stale.touch()  # as a killed run leaves it
    info.run_fiducials(cfg, "tiny", [fid], info.FiducialDesign(3, [0.1], 0), shared, say=lambda *_: None, workers=2)
    info.run_fiducials(cfg, "tiny", [fid], info.FiducialDesign(3, [0.1], 0), alone, say=lambda *_: None, workers=1)
    rows = [json.loads(line) for line in (shared / "costs.jsonl").read_text().splitlines()]
    assert len(rows) == 2 and all(r["sample_id"] == 3 and r["exit"] == 0 for r in rows)
    families = sorted(p.name for p in (shared / "tiny" / "s00003").glob("*.npz"))
    assert len(families) == 5 * 3 and not list((shared / "tiny").rglob("*.claim"))  # (centre, 2 x +-delta) x R
    a, b = (json.loads((d / "tiny" / "s00003.json").read_text())["channels"]["float"]["R3_d0.1"] for d in (shared, alone))
    assert a["crb_single"] == b["crb_single"] and a["crb_conditional_matched"] == b["crb_conditional_matched"]


def test_a_family_is_claimed_by_one_process_only(tmp_path):
    """The claim is exclusive: a second claim on a family fails while the first holds it, and a family on
    disk cannot be claimed."""
    from forcdecode.bench import information_films as info

    family = info.family_path(tmp_path, "tiny", 1, "c", 0)
    assert info._claim(family) and not info._claim(family)
    family.write_bytes(b"")
    info.claim_path(family).unlink()
    assert not info._claim(family) and not info.claim_path(family).exists()


def test_period_box_runs_the_spiral_fiducials_only_and_results_without_families_are_kept(tmp_path):
    """The period box (128 nm -> 272 nm, the spiral fiducials' period 103-133 nm held twice) runs only the
    fiducials of its regime; the laptop films run all. A result whose families are not on disk (a
    committed copy) survives `--summarize-only`'s re-analysis unchanged."""
    import json

    from forcdecode.bench import information_films as info

    fids = [{"sample_id": i, "regime": r} for i, r in enumerate(["K_eff<0", "domains", "spirals", "K_eff<0", "spirals"])]
    assert [f["sample_id"] for f in info.film_fiducials("period_box", fids)] == [2, 4]
    assert info.film_fiducials("laptop_8nm", fids) == fids
    assert 2 * info.FILMS["period_box"]["nx"] / 133 >= 2  # 2 nm cells: the box holds 2 of the longer period
    kept = tmp_path / "laptop_8nm" / "s00007.json"
    kept.parent.mkdir()
    kept.write_text(json.dumps({"film": "laptop_8nm", "sample_id": 7, "params": {}, "R": 8, "deltas": [0.1]}))
    assert info.reanalyse(tmp_path, say=lambda *_: None) == 0
    assert json.loads(kept.read_text())["sample_id"] == 7


def test_main_job_estimate_reproduces_the_measured_laptop_job_and_shrinks_draws_for_dearer_films():
    """At the laptop's cost the estimate is the measured main job (85-92 min wall on 2 cores, fresh clones
    of 2026-11-28); a film 3x dearer fits 2 h only with fewer draws, and one 20x dearer not at 500 draws."""
    from forcdecode.bench.information_films import MIN_DRAWS, main_job_estimate

    laptop = main_job_estimate(1.0)
    assert 85 / 60 <= laptop["wall_hours_2_cores"] <= 92 / 60 and laptop["eligible"]
    dear = main_job_estimate(3.0)
    assert dear["wall_hours_2_cores"] > 2 and MIN_DRAWS <= dear["draws_within_2h"] < 1000
    assert abs(main_job_estimate(3.0, draws=dear["draws_within_2h"])["wall_hours_2_cores"] - 2) < 0.01
    assert not main_job_estimate(20.0)["eligible"]


def test_paired_comparison_on_shared_fiducials():
    """paired_to: ratios film/reference on the fiducials both measured, per parameter; an unidentified
    (None) reference bound makes any finite film bound tighter."""
    from forcdecode.bench.information_films import paired_to

    def analysis(sid, matched, single):
        row = {"crb_conditional_matched": matched, "crb_single": single}
        return {"sample_id": sid, "names": ["K_u", "D"], "R": 8, "deltas": [0.1], "channels": {"float": {"R8_d0.1": row}}}

    film = [analysis(1, [0.01, 0.2], [0.001, 0.02]), analysis(2, [0.02, 0.1], [0.002, 0.01]), analysis(3, [1, 1], [1, 1])]
    ref = [analysis(1, [0.02, 0.4], [0.001, 0.04]), analysis(2, [0.01, None], [0.004, 0.01])]
    out = paired_to(film, ref, ["K_u", "D"])
    assert out["n_fiducials"] == 2 and out["sample_ids"] == [1, 2]
    k = out["per_parameter"]["K_u"]["crb_conditional_matched"]
    assert k["ratios"] == [0.5, 2.0] and k["median_ratio"] == 1.25 and k["film_tighter"] == 1
    d = out["per_parameter"]["D"]["crb_conditional_matched"]
    assert d["ratios"] == [0.5, 0.0] and d["film_tighter"] == 2
    assert out["per_parameter"]["D"]["crb_single"]["film_tighter"] == 1
    # a film at R = 4 against a reference at R = 8 that also has (noisier) R = 4 rows: the reference's own R
    small = [{**analysis(1, [0.01, 0.2], [0.001, 0.02]), "R": 4}]
    small[0]["channels"]["float"] = {"R4_d0.1": small[0]["channels"]["float"]["R8_d0.1"]}
    both = analysis(1, [0.02, 0.4], [0.001, 0.04])
    both["channels"]["float"]["R4_d0.1"] = {"crb_conditional_matched": [0.04, 0.8], "crb_single": [0.002, 0.08]}
    at8 = paired_to(small, [both], ["K_u", "D"])["per_parameter"]["K_u"]["crb_conditional_matched"]
    assert at8["ratios"] == [0.5]


def _film_row(matched, lw, eligible=True, regimes=None):
    row = {"main_job": {"eligible": eligible},
           "matched_bound_at_one_core_hour": dict(zip(("A_ex", "D", "N_pin"), matched)),
           "bound_at_one_core_hour": dict(zip(("A_ex", "D", "N_pin"), lw))}
    if regimes:
        row["regimes"] = regimes
    return row


def test_choose_film_decides_on_the_conservative_bound_not_ledoit_wolf():
    """The Ledoit–Wolf bound is 4x optimistic at R = 8 on the closed-form check: a film that wins only
    by it must lose; ineligible films, single-regime films and an unidentified parameter do not win."""
    from forcdecode.bench.information_films import choose_film

    films = {"a": _film_row([0.1, 0.2, 0.2], [0.001, 0.002, 0.002]),   # wins on LW only
             "b": _film_row([0.05, 0.1, 0.1], [0.01, 0.02, 0.02]),      # wins on the matched filter
             "c": _film_row([0.01, 0.01, 0.01], [0.001, 0.001, 0.001], eligible=False),
             "d": _film_row([0.01, 0.01, 0.01], [0.001, 0.001, 0.001], regimes=["spirals"])}
    choice = choose_film(films)
    assert choice["film"] == "b"
    assert choice["scores"]["b"] == pytest.approx((0.05 * 0.1 * 0.1) ** (1 / 3))
    assert choice["scores_ledoit_wolf"]["a"] < choice["scores_ledoit_wolf"]["b"]
    assert set(choice["scores"]) == {"a", "b"}
    assert choose_film({"a": _film_row([0.1, None, 0.2], [0.001, 0.002, 0.002])})["film"] is None


def test_stop_at_is_the_next_such_time_even_across_midnight():
    import datetime as dt

    from forcdecode.bench.information_cli import _stop_time
    from forcdecode.core.errors import ConfigError

    late = dt.datetime(2026, 11, 29, 23, 40, tzinfo=dt.timezone.utc)
    assert _stop_time("01:25", now=late) == dt.datetime(2026, 11, 30, 1, 25, tzinfo=dt.timezone.utc).timestamp()
    assert _stop_time("23:50", now=late) == dt.datetime(2026, 11, 29, 23, 50, tzinfo=dt.timezone.utc).timestamp()
    assert _stop_time(None) is None
    for bad in ("1:2:3", "25:00", "noon"):
        with pytest.raises(ConfigError, match="--stop-at"):
            _stop_time(bad, now=late)


def test_the_llg_film_has_the_laptop_films_disorder_realisations():
    """Common random numbers across protocols: realisation r of ``laptop_llg`` is drawn from the laptop
    film's stream (same grains, axes and pinning sites; the pinning treatment does not draw), no other
    film's, and the LLG film is differentiated in A_ex and D only."""
    from forcdecode.bench import information_films as info
    from forcdecode.config import load_config, shipped_config
    from forcdecode.micromag.build import build_film

    cfg = load_config(shipped_config("config"))
    draw = lambda film, sid, r: info.film_rng(cfg, film, sid, r).random(4)  # noqa: E731
    assert np.array_equal(draw("laptop_llg", 19, 2), draw("laptop", 19, 2))
    assert not np.array_equal(draw("laptop_llg", 19, 2), draw("laptop", 19, 3))
    assert not np.array_equal(draw("laptop_8nm", 19, 2), draw("laptop", 19, 2))
    assert info.FILMS["laptop_llg"]["names"] == ("A_ex", "D")
    params = {"Ms": 5.0e5, "A_ex": 1.5e-11, "K_u": 3.5e5, "D": 5e-4, "N_pin": 40, "sigma_theta_deg": 2.0,
              "sigma_K": 0.05}
    fcfg = info.film_config(cfg, "laptop", info.FILMS)
    _, _, full = build_film(fcfg, params, rng=info.film_rng(cfg, "laptop", 19, 2))
    _, _, slaved = build_film(fcfg, params, pinning="slaved", rng=info.film_rng(cfg, "laptop_llg", 19, 2))
    for key in ("K_u", "easy_axis", "grain_labels", "pinning_mask", "pinning_initial"):
        assert np.array_equal(getattr(full, key), getattr(slaved, key)), key


@pytest.mark.slow
def test_an_llg_family_on_a_tiny_film_switches_no_earlier_than_the_quasistatic_one(monkeypatch):
    """The bench's LLG film path runs the adaptive slew-rate protocol (forc.adaptive) on the quasi-static
    film's disorder. On an 8 x 8 film with strong anisotropy each quasi-static branch reverses in one
    avalanche (m_z = ±1 everywhere). At zero temperature a sweep at a finite rate cannot switch before the
    metastable minimum disappears, where the quasi-static protocol switches, and here the adaptive rate
    (fastest, 1 T/ns, where the susceptibility is small, as before an avalanche) delays it by a grid step
    or more: the descending branch switches at a field no less negative, every ascending curve at a
    field no lower, and some later."""
    from forcdecode.bench import information_films as info
    from forcdecode.config import load_config, shipped_config

    monkeypatch.setitem(info.FILMS, "tiny", dict(nx=8, ny=8, nz=1, n_grains=2, protocol="quasistatic",
                                                 names=("A_ex", "D")))
    monkeypatch.setitem(info.FILMS, "tiny_llg", dict(nx=8, ny=8, nz=1, n_grains=2, protocol="llg",
                                                     names=("A_ex", "D"), disorder_of="tiny"))
    cfg = load_config(shipped_config("config"))
    cfg["field"]["n_fields"] = 16
    base = {"Ms": 5.0e5, "A_ex": 1.5e-11, "K_u": 3.5e5, "D": 5e-4, "N_pin": 10, "sigma_theta_deg": 2.0,
            "sigma_K": 0.05}
    families = {film: info.simulate_family(cfg, film, base, 1, 0)["curves"] for film in ("tiny", "tiny_llg")}
    upper = np.isfinite(families["tiny"])
    assert upper.sum() == 16 * 17 // 2
    assert np.all(np.abs(families["tiny"][upper]) > 0.99)  # one avalanche each way
    assert np.array_equal(np.isfinite(families["tiny_llg"]), upper)  # (LLG records points mid-switch)
    assert np.all(np.abs(families["tiny_llg"][upper]) <= 1.0 + 1e-6)

    def descending_switch(curves):  # the last reversal field (index) still reversed
        return max(i for i in range(16) if curves[i, i] < 0)

    def ascending_switch(curves, i):  # the first applied field at which curve i is up again
        return next(j for j in range(i, 16) if curves[i, j] > 0)

    quasistatic, llg = families["tiny"], families["tiny_llg"]
    assert descending_switch(llg) <= descending_switch(quasistatic)
    rows = range(descending_switch(llg) + 1)
    delays = [ascending_switch(llg, i) - ascending_switch(quasistatic, i) for i in rows]
    assert min(delays) >= 0 and max(delays) >= 1


def test_the_bound_on_an_A_ex_D_combination_matches_the_closed_form(bench):
    """``matched_direction_crb`` on the closed-form ensemble: along a direction v of the plane of the two
    parameters that enter, the matched-filter bound sqrt(J_vᵀΣJ_v)/|J_v|² (J_v = J v, Σ the analytic
    covariance) within the tolerance; along an axis exactly ``matched_filter_crb``'s entry; never below
    the true conditional bound 1/sqrt(vᵀFv); the best direction beats both axes and stays above the
    largest eigenvalue's bound."""
    from forcdecode.bench.information import best_matched_direction, matched_direction_crb, matched_filter_crb

    f, _ = bench
    reals = range(R)
    center = np.stack([f(U, r) for r in reals])
    d, J = [], []
    for i in range(2):
        lo, hi = stencil(U[i], DELTA)
        up, um = U.copy(), U.copy()
        up[i], um[i] = hi, lo
        d.append(np.stack([f(up, r) - f(um, r) for r in reals]) / (hi - lo))
        J.append((check.analytic_mean(up, n_fields=N_FIELDS) - check.analytic_mean(um, n_fields=N_FIELDS)) / (hi - lo))
    d, J = np.stack(d), np.stack(J).T
    S = check.analytic_covariance(U, N_PARTICLES, NOISE_SD, n_fields=N_FIELDS)
    F = check.analytic_fisher(U, N_PARTICLES, NOISE_SD, n_fields=N_FIELDS)[:2, :2]
    for v in (np.array([1.0, 0.0]), np.array([0.6, -0.8]), np.array([1.0, 1.0]) / np.sqrt(2)):
        Jv = J @ v
        analytic = np.sqrt(Jv @ S @ Jv) / (Jv @ Jv)
        got = matched_direction_crb(center, d, (0, 1), 3 * v)  # the direction's length does not matter
        assert abs(got / analytic - 1) < TOLERANCE, (v, got, analytic)
        assert got >= 0.95 / np.sqrt(v @ F @ v)
    assert matched_direction_crb(center, d, (0, 1), np.array([0.0, 2.0])) == pytest.approx(
        matched_filter_crb(center, d)[1], rel=1e-12)
    best, v_best = best_matched_direction(center, d, (0, 1))
    assert best <= min(matched_filter_crb(center, d)) + 1e-12
    assert best >= 0.95 / np.sqrt(np.linalg.eigvalsh(F).max())
    assert np.linalg.norm(v_best) == pytest.approx(1.0)


def test_the_pooled_matched_bound_agrees_with_the_centres_where_the_scatter_is_the_same(bench):
    """On the closed-form ensemble (Σ nearly the same across a small stencil) the bound with the scatter
    pooled over the stencil points agrees with the centre-only matched bound at R = 1000 and, at R = 4,
    scatters less about it over disjoint sets of four realisations (the reason to have it)."""
    from forcdecode.bench.information import matched_filter_crb, matched_filter_crb_pooled

    f, _ = bench

    def families(reals):
        center = np.stack([f(U, r) for r in reals])
        plus, minus, steps = [], [], []
        for i in range(2):
            lo, hi = stencil(U[i], DELTA)
            up, um = U.copy(), U.copy()
            up[i], um[i] = hi, lo
            plus.append(np.stack([f(up, r) for r in reals]))
            minus.append(np.stack([f(um, r) for r in reals]))
            steps.append(hi - lo)
        plus, minus = np.stack(plus), np.stack(minus)
        return center, plus, minus, (plus - minus) / np.array(steps)[:, None, None]

    center, plus, minus, d = families(range(R))
    groups = [center, *plus, *minus]
    assert np.allclose(matched_filter_crb_pooled(groups, d), matched_filter_crb(center, d), rtol=TOLERANCE)
    reference = matched_filter_crb(center, d)
    spread = {"centre": [], "pooled": []}
    for start in range(0, 160, 4):
        c, p, m, dd = families(range(start, start + 4))
        spread["centre"].append(np.log(matched_filter_crb(c, dd) / reference))
        spread["pooled"].append(np.log(matched_filter_crb_pooled([c, *p, *m], dd) / reference))
    sd = {k: np.std(np.array(v), axis=0) for k, v in spread.items()}
    assert np.all(sd["pooled"] < 0.8 * sd["centre"]), sd


def test_the_figure_puts_every_film_in_its_legend_in_a_fixed_colour():
    """The LLG film has no K_u panel, where the old legend lived: it must still be in the legend, and a
    film keeps its colour whichever films the summary holds (its place in FILMS)."""
    import matplotlib.pyplot as plt

    from forcdecode.bench.information_films import draw_figure

    def row(names, cost):
        stats = {n: {"crb_single_median": 0.01, "crb_single_iqr": [0.005, 0.02],
                     "crb_conditional_matched_median": None if n == "D" else 0.1,
                     "crb_conditional_matched_iqr": [0.05, None]} for n in names}
        return {"per_parameter": stats, "image": {"per_parameter": stats}, "cost_core_s_per_family": cost}

    def legend_colours(films):
        fig = draw_figure({"films": films})
        handles = fig.legends[0].legend_handles
        colours = {h.get_label(): h.get_color() for h in handles}
        plt.close(fig)
        return colours

    both = legend_colours({"laptop_llg": row(("A_ex", "D"), 600.0), "laptop": row(("K_u", "A_ex", "D"), 2.0)})
    assert {"laptop", "laptop_llg"} <= set(both)
    assert [label for label in both if label in ("laptop", "laptop_llg")] == ["laptop", "laptop_llg"]
    alone = legend_colours({"laptop_llg": row(("A_ex", "D"), 600.0)})
    assert alone["laptop_llg"] == both["laptop_llg"] != both["laptop"]
