"""Shape functions of one Euler–Bernoulli link and their constant integrals (docs/mechanics.md).

``make_basis(kind, count, length, linear_density)`` is the one entry point the model needs; the
integrals (``basis.integrals``) are for unit density and unit stiffness, to be scaled by ρ and EI.
"""

from __future__ import annotations

from .base import ShapeBasis, ShapeIntegrals, integrals_from_rule
from .eigen import ClampedFreeBasis, clamped_free_roots
from .fe import HermiteFEBasis
from .polynomial import PolynomialBasis

__all__ = [
    "KINDS",
    "ClampedFreeBasis",
    "HermiteFEBasis",
    "PolynomialBasis",
    "ShapeBasis",
    "ShapeIntegrals",
    "clamped_free_roots",
    "integrals_from_rule",
    "make_basis",
]

_FAMILIES: dict[str, type[ShapeBasis]] = {
    cls.kind: cls for cls in (ClampedFreeBasis, PolynomialBasis, HermiteFEBasis)
}
KINDS: tuple[str, ...] = tuple(_FAMILIES)


def make_basis(kind: str, count: int, length: float, linear_density: float = 1.0) -> ShapeBasis:
    """Shape basis of one link.

    ``count`` is the number of modes (``"clamped-free"``), of polynomials (``"polynomial"``) or of
    elements (``"fe"``, giving 2·count coordinates). ``linear_density`` only sets the mass
    normalisation of the eigenfunctions.
    """
    family = _FAMILIES.get(kind) if isinstance(kind, str) else None
    if family is None:
        raise ValueError(f"unknown shape kind {kind!r}: expected one of {', '.join(map(repr, KINDS))}")
    return family(count, length, linear_density)
