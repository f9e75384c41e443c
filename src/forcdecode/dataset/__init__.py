"""The training set: parameter draw, screening, FORC families, rasterization, merge."""
