"""Neural posterior estimation (NPE): the joint posterior p(θ | FORC image, M_s) of the learned
parameters θ = (N_pin, A_ex, K_u, D, σ_θ, σ_K), normalized to u ∈ [0, 1] by the configured bounds
(K_u on a log scale, as in the parameter table).

Model: a CNN embedding of the image and M_s (the small head's two 3×3 convolutions and 4×4 average
pool, M_s joined as in Alice, then a dense layer of ``width`` features) conditions a neural spline
flow (``zuko.flows.NSF``: autoregressive rational-quadratic splines; zuko, not a hand-written flow).
Everything is fitted on the workflow's train split with early stopping on its validation split (the
same hash split as Alice: ``splits.py``); the test split serves only the calibration
(``calibration.py``). Default summary (``features``), for the few hundred families of a laptop run:

1. the CNN and a linear head are fitted as a regression of the six standardized logits (MSE, early
   stopping on validation): the CNN learns features that carry the posterior means;
2. the CNN is then fixed, and the flow learns p(θ | CNN features, M_s) by maximum likelihood (early
   stopping on the validation likelihood).

``joint`` trains CNN and flow together by the likelihood alone (its early stopping also answers to
the parameters the image does not tell). ``crossfit`` conditions the flow on the regression's six
outputs, the training samples' taken out of fold (K regressions, each blind to its fold, as Bob's
errors are), so that the flow sees summaries as noisy as a new image's. Chosen on validation
likelihood, 5-fold cross-validation over the 148 laptop families: features 6.99 and 7.12 nats (two
weight seeds), crossfit 7.25 (calibration alike, 5 more regressions); on a 104-family snapshot joint
and features were alike (7.52, 7.58).

Bounded support: the flow lives in logit space. u is squeezed to [ε, 1 − ε] (ε = 1e-3, so a value
on a bound, e.g. N_pin = 0, stays finite), z = logit(u), standardized by the training split's mean
and spread (the spline acts on [−5, 5]); draws map back by the sigmoid and lie inside [0, 1] by
construction (no clipping of the density). N_pin is a count: its 256 levels on the laptop grid are
0.004 apart in u, far below any posterior width, and it is treated as continuous.

Every random number derives from the config seed through the stream ``posterior`` (weights, batch
order, dropout, draws); the same model and seed give the same draws after a save and a reload.

The package: ``flow`` (settings, the bounded latent space, the flow's coordinates, the embeddings
and ``PosteriorNet``), ``estimator`` (``PosteriorEstimator``: draws, density; summaries of draws),
``training`` (``fit_posterior``, the workflow stage ``train_posterior``), ``calibration`` (the held-out
recalibration and the split diagnostics) and ``file_format`` (the model file).
"""

from .calibration import (fit_held_out_recalibration, gated_recalibration_record, recalibration_families,
                          recalibration_holdout, split_diagnostics)
from .estimator import RECALIBRATION_REFERENCE_DRAWS, PosteriorEstimator, posterior_prediction, summarize
from .file_format import FORMAT
from .flow import (BOUNDED_SUPPORT, EMBEDDINGS, SQUEEZE, SUMMARIES, ConvEmbedding, MLPEmbedding, PosteriorNet, _float32,
                   from_coordinates, from_latent, posterior_settings, to_coordinates, to_latent)
from .training import PosteriorFit, fit_posterior, train_posterior

__all__ = ["FORMAT", "BOUNDED_SUPPORT", "posterior_settings", "to_latent", "from_latent", "PosteriorNet",
           "PosteriorEstimator", "PosteriorFit", "fit_posterior", "gated_recalibration_record", "fit_held_out_recalibration",
           "recalibration_families", "recalibration_holdout",
           "summarize", "posterior_prediction",
           "split_diagnostics", "train_posterior"]
