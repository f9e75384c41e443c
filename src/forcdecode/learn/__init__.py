"""Learning: per-parameter CNNs ("Alice") with distribution-matching outputs (and, later, "Bob")."""
