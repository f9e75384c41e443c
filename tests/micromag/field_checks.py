"""Shared check of the engine's fields against their energies (finite differences)."""


def field_by_finite_difference(energy, m, index, moment_per_cell, B_ext, h=1e-6):
    """−(1/(M_s V)) ∂E/∂m at one component of one cell (``index`` = (c, k, j, i)), central difference (T).

    ``energy(m, B_ext)`` in joules, ``moment_per_cell`` = M_s·V in A·m²."""
    mp, mm = m.copy(), m.copy()
    mp[index] += h
    mm[index] -= h
    return -(energy(mp, B_ext) - energy(mm, B_ext)) / (2 * h) / moment_per_cell
