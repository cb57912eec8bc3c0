"""Elementary operators of the scanner model: play (eqs 3-6), creep (eqs 1-2) and the
one-sided dead zones of Kuhnen's asymmetry map (eq 8').

The public functions check their inputs and call the private numba kernels in
:mod:`piezocomp.operators._kernels`. A new operator family for the identified model goes here (the
simulator's own physics lives in :mod:`piezocomp.virtual_afm`); the model (:mod:`piezocomp.model`),
its inverse (:mod:`piezocomp.inverse`) and the estimation
(:mod:`piezocomp.identification.estimation.parameters`, the parameter vector and gradient) are
written for Prandtl-Ishlinskii play operators and would learn the new family too. Identifying a
family on a simulator of the same family checks only the mathematics: validating it needs a virtual
scanner whose physics is another family (the simulator's :mod:`piezocomp.virtual_afm.preisach` is
physics, not a model to compensate with). Imports nothing else of the package but ``_validation``.
"""

from piezocomp.operators.creep import creep_bank, creep_poles
from piezocomp.operators.dead_zone import dead_zone_map, inverse_dead_zones
from piezocomp.operators.play import play_bank, play_operator

__all__ = [
    "creep_bank",
    "creep_poles",
    "dead_zone_map",
    "inverse_dead_zones",
    "play_bank",
    "play_operator",
]
