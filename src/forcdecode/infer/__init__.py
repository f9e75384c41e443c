"""Per-file inference by simulation, between learning and the loop: re-simulation of a Hamiltonian
(``resimulate``), the refinement of one family's posterior by rounds of simulations (``fit``,
``fit_cli``, ``fit_step_cli``), its calibrated posterior-predictive check (``predictive_check``) and
the posterior loop on the simulated test set (``posterior_predictive``, ``posterior_loop_cli``)."""
