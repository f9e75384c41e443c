"""Independent reference implementations used to cross-check and benchmark our own engine.

These are optional: they need the ``reference`` extra (``pip install -e .[reference]``). Importing
this package is cheap; the reference code itself (magnum.np, PyTorch) is imported only when an
adapter object is constructed.
"""

from .magnumnp_film import MagnumFilm, MagnumGrid, MagnumMaterial, magnumnp_available

__all__ = ["MagnumFilm", "MagnumGrid", "MagnumMaterial", "magnumnp_available"]
