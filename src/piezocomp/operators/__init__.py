"""Elementary operators of the scanner model: play (eqs 3-6) and creep (eqs 1-2).

The public functions check their inputs and call the private numba kernels in
:mod:`piezocomp.operators._kernels`.
"""

from piezocomp.operators.creep import creep_bank, creep_poles
from piezocomp.operators.play import play_bank, play_operator

__all__ = ["creep_bank", "creep_poles", "play_bank", "play_operator"]
