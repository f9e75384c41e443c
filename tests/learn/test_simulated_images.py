"""K_u is learned from simulated FORC images, beyond what M_s alone tells.

The fixture holds real simulated families (the laptop dataset's images, 2×2-averaged to 32×32;
written by make_forc_fixture.py), not synthetic bars. Alice is trained on the hash split's train
part with early stopping on validation; on the test part her K_u must beat the M_s-only k-NN
baseline (k chosen on validation) with a bootstrap 90 % interval of the skill above zero.
"""

from pathlib import Path

import numpy as np
import torch

from forcdecode.core.parameters import DEFAULT_BOUNDS, normalize
from forcdecode.learn.scoring import accuracy_with_intervals, fit_ms_only, knn_median
from forcdecode.learn.splits import assign_splits
from forcdecode.learn.train import AliceSettings, fit_alice

FIXTURE = Path(__file__).with_name("data") / "laptop_forc_32px.npz"


def test_alice_learns_K_u_from_simulated_forc_images_beyond_ms():
    torch.set_num_threads(1)
    data = np.load(FIXTURE)
    images, sample_id = data["images"], data["sample_id"]
    ms = normalize("Ms", data["Ms"], DEFAULT_BOUNDS)
    u = normalize("K_u", data["K_u"], DEFAULT_BOUNDS)
    splits = assign_splits(sample_id, 20261122, (0.6, 0.2, 0.0, 0.2))
    train, val, test = splits["train"], splits["validation"], splits["test"]
    alice = fit_alice(images, ms, u, train, val, AliceSettings(model="small", width=32, epochs=80, batch_size=8,
                                                               lr=1.0, patience=15, seed=4))
    prediction = alice.predict(images[test], ms[test])
    k = fit_ms_only(ms[train], u[train], ms[val], u[val])
    ms_only = knn_median(ms[train], u[train], ms[test], k)
    block = accuracy_with_intervals(u[test], prediction, ms_only, np.full(len(test), np.median(u[train])),
                                    np.ones(len(test)), np.random.default_rng(0), n_boot=1000)
    print({k: block[k] for k in ("mae", "skill_vs_ms_only", "skill_vs_ms_only_ci90", "pearson_r")}, "n_test", len(test))
    assert block["skill_vs_ms_only_ci90"][0] > 0.0, block
    assert block["skill_vs_ms_only"] > 0.3 and block["pearson_r"] > 0.8, block
