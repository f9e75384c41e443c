"""A candidate must beat what a different film of the same Hamiltonian gives it (the realisation
floor): ``analyse_residual(null_gain=...)`` and ``null_gains``."""

import numpy as np

from forcdecode.loop.effects import HAMILTONIAN_CHANGE
from forcdecode.loop.physics_effects import analyse_residual, null_gains


def family(coercivity, n=40, width=0.1):
    fields = np.linspace(-1, 1, n)
    out = np.full((n, n), np.nan)
    for i, hr in enumerate(fields):
        down = 0.5 * (1 - np.tanh((hr + coercivity) / width))
        out[i, i:] = down * np.tanh((fields[i:] - coercivity) / width) + (1 - down)
    return fields, out


def realisation(seed, n=40):
    """A film of the same Hamiltonian on other disorder: its coercivity differs by a few per cent."""
    rng = np.random.default_rng(seed)
    return family(0.3 * (1 + 0.08 * rng.normal()), n)[1] + 0.002 * rng.normal(size=(n, n))


def test_realisation_difference_is_not_named_an_effect_once_calibrated():
    fields, base = family(0.3)
    measured = realisation(10)  # no effect: another film
    plain = analyse_residual(measured, base, fields, thermal=True)
    gains = null_gains([realisation(s) for s in (1, 2, 3)], base, fields, thermal=True)
    calibrated = analyse_residual(measured, base, fields, thermal=True, null_gain=gains)
    assert plain["chosen"] != "none"  # without the floor a coercivity-like candidate covers the film difference
    assert calibrated["chosen"] == "none"
    assert gains[plain["chosen"]]["relative"] > 0.3


def test_an_effect_well_above_the_floor_is_still_named():
    fields, base = family(0.3)
    measured = realisation(10) + 0.15 * fields[None, :]  # a substrate background of 15 % per tesla
    gains = null_gains([realisation(s) for s in (1, 2, 3)], base, fields, thermal=True, noise_sigma=0.002, seed=4)
    result = analyse_residual(measured, base, fields, thermal=True, null_gain=gains)
    assert result["chosen"].startswith("background")
    assert result["candidates"][result["chosen"]]["beats_null"]
    assert result["heldout_rms_after"] < 0.6 * result["heldout_rms_before"]


def test_noise_makes_the_null_of_identical_films_harmless():
    """Two realisations that agree exactly leave no residual: without the measurement's noise every
    candidate's relative gain over it is arbitrary, and a real effect could be blocked."""
    fields, base = family(0.3)
    gains = null_gains([base.copy()], base, fields, thermal=False, noise_sigma=0.003, seed=1)
    assert max(g["relative"] for g in gains.values()) < 0.2
    measured = base + 0.1 * fields[None, :] + 0.003 * np.random.default_rng(5).normal(size=base.shape)
    result = analyse_residual(measured, base, fields, thermal=False, null_gain=gains)
    assert result["chosen"] == "background"


def test_the_null_gain_of_a_hamiltonian_change():
    """``null_gains(hamiltonian_floor=True)``: what K_u moved along its neighbourhood gains on films
    without an effect (here realisations whose coercivity differs by a few per cent, which such a change
    covers), the floor of the refit's own change (``refit.refit_ambiguity``); off by default."""
    fields, base = family(0.3)
    neighbourhood = {c: family(0.3 * (1 + c))[1] for c in (-0.12, -0.06, 0.06, 0.12)}
    films = [realisation(s) for s in (1, 2)]
    plain = null_gains(films, base, fields, thermal=False, hamiltonian_families=neighbourhood)
    floor = null_gains(films, base, fields, thermal=False, hamiltonian_families=neighbourhood, hamiltonian_floor=True)
    assert HAMILTONIAN_CHANGE not in plain and floor[HAMILTONIAN_CHANGE]["relative"] > 0.5
    assert {k: v for k, v in floor.items() if k != HAMILTONIAN_CHANGE} == plain
