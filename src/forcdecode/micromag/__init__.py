"""Zero-temperature micromagnetic engine for periodic perpendicular films (numba).

One module per energy term (``exchange``, ``anisotropy``, ``dmi``, ``demag``, ``zeeman``; optional
``interlayer`` coupling across a spacer), the combined effective field (``effective_field``), the
quasi-static minimizer (``minimize``), the adaptive RK45 LLG integrator (``llg``), the seed paper's
disorder (``disorder``) and the user-facing ``Film``.
"""

from .constants import GAMMA_LL, MU0
from .disorder import FilmExtras, FilmMaterial, disordered_film, draw_disorder
from .film import TERMS, Film, SimulationError
from .mesh import Mesh

__all__ = ["GAMMA_LL", "MU0", "TERMS", "Film", "FilmExtras", "FilmMaterial", "Mesh", "SimulationError", "disordered_film",
           "draw_disorder"]
