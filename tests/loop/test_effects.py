"""Undeclared measured-side effects are named, and a clean control is left alone."""

import numpy as np
import pytest

from forcdecode.loop.effects import _offset_family, select_effect


def synthetic_family(n=48):
    """A smooth Preisach-like family on the grid: m(H_r, H) with coercivity 0.3 T."""
    fields = np.linspace(-1, 1, n)
    sim = np.full((n, n), np.nan)
    for i, hr in enumerate(fields):
        h = fields[i:]
        down = 0.5 * (1 - np.tanh((hr + 0.3) / 0.12))  # fraction reversed at H_r
        sim[i, i:] = down * np.tanh((h - 0.3) / 0.12) + (1 - down) * 1.0 - 0.02 * (1 - h)
    return fields, sim


def measured_with(effect, size, seed):
    fields, sim = synthetic_family()
    n = fields.size
    order = np.linspace(0, 1, n)[::-1]  # curves measured from high H_r to low (MicroMag order)
    H = fields[None, :]
    m = sim.copy()
    if effect == "background":
        m = sim + size * H
    elif effect == "field_offset":
        # the instrument reports every field (reversal fields too) off by ``size``; the curves are
        # put back on the grid as measured files are (nearest row, linear in H)
        from forcdecode.forc.raster import resample_curves

        m = resample_curves(fields + size, [(fields[i:] + size, sim[i, i:]) for i in range(n)], 1.0, n)
    elif effect == "additive_drift":
        m = sim + size * order[:, None]
    elif effect == "multiplicative_drift":
        m = sim * (1 + size * order[:, None])
    elif effect == "scale":
        m = size * sim
    rng = np.random.default_rng(seed)
    return fields, sim, m + 0.003 * rng.normal(size=m.shape), order


@pytest.mark.parametrize("effect,size", [("background", 0.1), ("field_offset", 0.02), ("additive_drift", 0.03),
                                         ("multiplicative_drift", 0.04), ("scale", 0.9)])
@pytest.mark.parametrize("seed", [0, 1])
def test_undeclared_effect_is_named_and_cuts_the_heldout_error(effect, size, seed):
    fields, sim, measured, order = measured_with(effect, size, seed)
    result = select_effect(measured, sim, fields, order, seed=seed)
    assert result["chosen"] == effect, {k: v["heldout_rms"] for k, v in result["candidates"].items()}
    assert result["heldout_rms_after"] < 0.5 * result["heldout_rms_before"]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_control_without_effect_is_left_alone(seed):
    fields, sim, measured, order = measured_with("none", 0.0, seed)
    result = select_effect(measured, sim, fields, order, seed=seed)
    assert result["chosen"] == "none"


def test_undeclared_background_in_a_simulated_instrument_file(tmp_path):
    """Simulator → + substrate background (10 % of the film moment at 1 T) + noise → MicroMag file →
    reader → grid → effect selection against the clean re-simulation: the background is named."""
    from pathlib import Path

    import yaml

    from forcdecode.dataset.params import draw_parameters
    from forcdecode.micromag.build import mesh_from_config
    from forcdecode.forc.raster import resample_curves
    from forcdecode.infer.resimulate import resimulate
    from forcdecode.measured import read_forc
    from forcdecode.measured.writers import write_micromag_0015

    cfg = yaml.safe_load((Path(__file__).resolve().parents[2] / "config" / "test.yaml").read_text())
    cfg["field"]["n_fields"] = 24
    params = {**draw_parameters(1, 0), "Ms": 6e5, "A_ex": 1.0e-11, "K_u": 6e5, "D": 1e-3, "N_pin": 2,
              "sigma_theta_deg": 5.0, "sigma_K": 0.1}
    truth = resimulate(cfg, params, n_profiles=1)
    mesh = mesh_from_config(cfg)
    moment_scale = params["Ms"] * mesh.n_cells * mesh.cell_volume  # A·m² of the film at m = 1
    fields = np.linspace(-1, 1, 24)
    rng = np.random.default_rng(4)
    curves = []
    for i in range(24):
        m = truth[i, i:] + 0.10 * fields[i:] + 0.002 * rng.normal(size=24 - i)
        curves.append((fields[i:], m * moment_scale))
    data = read_forc(write_micromag_0015(tmp_path / "film.frc", fields, curves), drift_correction=False)
    measured = resample_curves([c.reversal_field_T for c in data.curves],
                               [(c.field_T, c.moment_Am2 / moment_scale) for c in data.curves], 1.0, 24)
    result = select_effect(measured, truth, fields, every_k=3)
    assert result["chosen"] == "background"
    assert result["candidates"]["background"]["parameters"]["chi_per_T"] == pytest.approx(0.10, abs=0.01)
    assert result["heldout_rms_after"] < 0.3 * result["heldout_rms_before"]


def test_a_consistent_candidate_is_not_hidden_behind_a_noisier_tie():
    """Stepwise selection: the best mean at a level fails the bootstrap (its gain lives on a few
    curves), a candidate with the same mean gain on every curve passes: it is chosen, not "none"."""
    from forcdecode.core.streams import stream_rng
    from forcdecode.loop.effects import choose_candidate

    none = np.ones(24)
    none[:2] = 10.0  # two curves carry most of the base model's error
    noisy = np.full(24, 1.05)
    noisy[:2] = 0.0  # fixes those two, a little worse everywhere else: its gain rests on two curves
    consistent = 0.56 * none  # 44 % less on every curve
    chosen, scores = choose_candidate({"none": none, "noisy": noisy, "consistent": consistent},
                                      {"none": 0, "noisy": 1, "consistent": 1}, stream_rng(1, "bootstrap", "t"), 2000)
    assert np.mean(noisy) < np.mean(consistent)
    assert chosen == "consistent"


def test_an_effect_shown_apart_from_the_held_out_curves_needs_only_a_lower_held_out_error():
    """A field shift the loop's own symmetry shows (``evidenced``) shows on the few held-out curves that
    cross the switching region: 65 % less error in all, all of it on one curve of six, two others a
    little worse. The bootstrap bound over curves refuses it; evidenced, it is chosen. A candidate
    that does not lower the mean by more than the 5 % margin is refused either way."""
    from forcdecode.core.streams import stream_rng
    from forcdecode.loop.effects import choose_candidate

    none = np.array([15.1, 19.0, 161.0, 0.11, 0.07, 0.02])
    shift = np.array([16.1, 20.4, 31.4, 0.11, 0.08, 0.02])
    flat = none * 0.97
    n = {"none": 0, "shift": 1, "flat": 1}

    def choose(evidenced):
        return choose_candidate({"none": none, "shift": shift, "flat": flat}, n, stream_rng(1, "bootstrap", "e"), 2000,
                                evidenced=evidenced)

    assert choose(())[0] == "none"
    chosen, scores = choose({"shift"})
    assert chosen == "shift" and scores["shift"]["accepted"]
    assert choose({"flat"})[0] == "none"


def _offset_family_curve_by_curve(sim, fields, delta):
    """The field-offset family as first written: each curve with np.interp (the reference of the vectorized one)."""
    n = len(fields)
    rows = int(np.rint(delta / (fields[1] - fields[0])))
    out = np.full(sim.shape, np.nan)
    for i in range(n):
        k = min(max(i - rows, 0), n - 1)
        curve = sim[k].copy()
        curve[:k] = curve[k]
        out[i, i:] = np.interp(np.clip(fields[i:] - delta, fields[0], fields[-1]), fields, curve)
    return np.where(np.isfinite(sim), out, np.nan)


def test_the_offset_family_is_np_interp_curve_by_curve_bit_for_bit():
    rng = np.random.default_rng(3)
    for n in (16, 33, 64):
        fields = np.linspace(-1, 1, n)
        step = fields[1] - fields[0]
        upper = np.triu(np.ones((n, n), dtype=bool))
        for trial in range(150):
            sim = np.where(upper, np.tanh(0.1 * rng.normal(size=(n, n)).cumsum(axis=1)), np.nan)
            for _ in range(int(rng.integers(0, 4))):  # holes: np.interp's rules around a NaN
                sim[rng.integers(n), rng.integers(n)] = np.nan
            if trial % 11 == 0:  # flat stretches: its rule for equal neighbours
                sim = np.where(upper, np.round(3 * sim) / 3, np.nan)
            delta = float(rng.choice([0.05 * rng.normal(), 0.5 * rng.normal(), 0.0, step * rng.integers(-5, 5),
                                      0.5 * step, -0.5 * step, 1.5, -3.0]))
            expected = _offset_family_curve_by_curve(sim, fields, delta)
            assert np.array_equal(_offset_family(sim, fields, delta), expected, equal_nan=True), (n, trial, delta)
