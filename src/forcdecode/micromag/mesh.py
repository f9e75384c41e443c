"""The finite-difference grid of a film: nx × ny × nz cells, periodic in x and y, open in z."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Mesh:
    """A regular grid of rectangular cells.

    Arrays on the mesh are laid out ``(nz, ny, nx)`` for scalars and ``(3, nz, ny, nx)`` for
    vectors (component first), so that each component of each layer is one contiguous 2D image
    for the in-plane FFTs. Cell sizes are in metres. The film is infinite (periodic) in x and y
    and has ``nz`` layers of thickness ``dz`` stacked along z.
    """

    nx: int
    ny: int
    nz: int
    dx: float
    dy: float
    dz: float

    def __post_init__(self):
        for name in ("nx", "ny", "nz"):
            if int(getattr(self, name)) < 1:
                raise ValueError(f"Mesh.{name} must be a positive integer, got {getattr(self, name)!r}")
        for name in ("dx", "dy", "dz"):
            value = float(getattr(self, name))
            if not (0.0 < value < 1e-6):
                raise ValueError(f"Mesh.{name} must be a cell size in metres in (0, 1e-6), got {value!r}")

    @property
    def shape(self) -> tuple[int, int, int]:
        """Scalar-field shape (nz, ny, nx)."""
        return (self.nz, self.ny, self.nx)

    @property
    def vector_shape(self) -> tuple[int, int, int, int]:
        """Vector-field shape (3, nz, ny, nx)."""
        return (3, self.nz, self.ny, self.nx)

    @property
    def n_cells(self) -> int:
        return self.nx * self.ny * self.nz

    @property
    def cell_volume(self) -> float:
        """Volume of one cell in m³."""
        return self.dx * self.dy * self.dz
