"""core.prior: the one law of the draw; its draw is the one the datasets were made with, bit for bit."""

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest

from forcdecode.core.prior import Prior, PriorError
from forcdecode.dataset.params import (draw_log_density, draw_parameters, draw_prior_cdf, draw_prior_ppf,
                                       draw_prior_quantiles)

ORIGINAL_DIGEST = "3ac380fbd1aba8800b87e7c7da470801efa1ac70904d8b7f3d10b961833c95b5"
"""sha256 of the draw as written before the Prior object (commit f9b42ae, dataset/params.py)."""

REFERENCE = Path(__file__).parent / "data" / "prior_draws_reference.json"
"""300 draws per class (seed 7), densities, CDFs, inverse CDFs and quantiles, as the datasets were made:
written by ``python tests/core/test_prior.py`` on an AVX-512 machine (AMD EPYC, numpy 2.4.6) where their
sha256 (``_digest``) was 3ac380fb…95b5, the hash of the draw as written before the Prior object (commit
f9b42ae, dataset/params.py): the refactor kept every bit there.

The comparison allows round-off and no more (relative 1e-12; pinning counts exact): numpy's exp and log
dispatch on the CPU (its AVX-512 loops differ from the AVX2 ones in the last bits; checked with
NPY_DISABLE_CPU_FEATURES="X86_V4 AVX512_ICL", under which the digest changes and this test passes), and
a bit-for-bit hash failed CI on a machine without AVX-512 (2026-12-02)."""


def _record() -> dict:
    """What the test compares: per prior class, the draws and the marginals' values."""
    out = {}
    for prior in ("paper", "perpendicular"):
        draws = [draw_parameters(7, i, prior=prior) for i in range(300)]
        u = np.random.default_rng(0).random((50, 3))
        Ms = np.linspace(3e5, 1.3e6, 50)
        rec = {"draws": draws, "log_density": draw_log_density(u, ("K_u", "A_ex", "D"), Ms, prior=prior).tolist()}
        for n in ("K_u", "A_ex", "D"):
            rec[f"cdf_{n}"] = draw_prior_cdf(n, u[:, 0], Ms[:5].repeat(10), prior=prior).tolist()
            rec[f"ppf_{n}"] = draw_prior_ppf(n, u[:, 1], Ms[:5].repeat(10), prior=prior).tolist()
            rec[f"quantiles_{n}"] = draw_prior_quantiles(n, 8e5, [0.05, 0.5, 0.95], prior=prior).tolist()
        out[prior] = rec
    return out


def _digest(record: dict) -> str:
    """The original bit-for-bit hash of the same values (kept to show which machine wrote the reference):
    each draw's sorted JSON, then the marginals' float64 bytes, class by class."""
    h = hashlib.sha256()
    for prior in ("paper", "perpendicular"):
        rec = record[prior]
        for draw in rec["draws"]:
            h.update(json.dumps(draw, sort_keys=True).encode())
        h.update(np.asarray(rec["log_density"], float).tobytes())
        for n in ("K_u", "A_ex", "D"):
            for key in ("cdf", "ppf", "quantiles"):
                h.update(np.asarray(rec[f"{key}_{n}"], float).tobytes())
    return h.hexdigest()


def test_the_draw_and_its_marginals_are_those_the_datasets_were_made_with():
    reference, now = json.loads(REFERENCE.read_text()), _record()
    assert set(now) == set(reference)
    for prior, rec in reference.items():
        assert len(now[prior]["draws"]) == len(rec["draws"])
        for i, (a, b) in enumerate(zip(now[prior]["draws"], rec["draws"])):
            assert a.keys() == b.keys() and a["N_pin"] == b["N_pin"], (prior, i)
            for k in a:
                assert a[k] == pytest.approx(b[k], rel=1e-12, abs=0), (prior, i, k)
        for key in set(rec) - {"draws"}:
            np.testing.assert_allclose(now[prior][key], rec[key], rtol=1e-12, atol=0, err_msg=f"{prior} {key}")


def test_the_reference_is_the_original_draw_bit_for_bit():
    """The committed values hash to the digest of the draw the datasets were made with (on any CPU: the
    hash reads the file, not a fresh draw)."""
    assert _digest(json.loads(REFERENCE.read_text())) == ORIGINAL_DIGEST


def test_the_reference_comparison_fails_on_a_changed_draw():
    """The tolerance is round-off, not a change of the law: one more variate drawn first moves every draw."""
    reference = json.loads(REFERENCE.read_text())["perpendicular"]["draws"][3]
    changed = draw_parameters(8, 3, prior="perpendicular")
    assert any(changed[k] != pytest.approx(reference[k], rel=1e-12, abs=0) for k in reference)


@pytest.mark.parametrize("prior_class", ["paper", "perpendicular"])
def test_samples_follow_the_cdf_and_the_density_integrates_to_one(prior_class):
    prior = Prior(prior_class)
    Ms = 6e5
    draws = [prior.sample(3, i) for i in range(4000)]
    at = [d for d in draws if abs(d["Ms"] - Ms) < 1e5]  # M_s is uniform: condition on a slice near 600 kA/m
    for name in ("K_u", "A_ex", "D"):
        v = np.sort(prior.cdf(name, prior.normalize(name, np.array([d[name] for d in at])), np.array([d["Ms"] for d in at])))
        ks = np.max(np.abs(v - (np.arange(1, len(v) + 1) / len(v))))
        assert ks < 1.63 / np.sqrt(len(v)) + 0.02, (name, ks)  # KS 1 % level (+ the slice's M_s spread)
        mid = (np.arange(20000) + 0.5) / 20000
        mass = np.exp(prior.log_prob(mid[:, None], (name,), Ms)).mean()
        assert mass == pytest.approx(1.0, abs=2e-3), name
        v = np.array([0.1, 0.5, 0.9])
        assert prior.cdf(name, prior.ppf(name, v, Ms), Ms) == pytest.approx(v, abs=2e-3)


def test_a_bound_set_without_a_perpendicular_film_is_refused():
    with pytest.raises(PriorError, match="K_eff"):
        Prior("perpendicular", {"Ms": [1.3e6, 1.4e6], "K_u": [1e3, 1e6]}).k_u_floor_u(1.4e6)
    assert Prior("paper").k_u_floor_u(1.4e6) == 0.0


if __name__ == "__main__":  # rewrite the reference (only where the draw law itself was meant to change)
    REFERENCE.parent.mkdir(exist_ok=True)
    record = _record()
    REFERENCE.write_text(json.dumps(record, sort_keys=True) + "\n")
    print("wrote", REFERENCE, "digest", _digest(record))
