"""piezocomp: sensorless compensation of piezo scanner creep and hysteresis.

Implements Mokaberi & Requicha, "Compensation of Scanner Creep and Hysteresis for AFM
Nanomanipulation", IEEE T-ASE 5(2), 2008. Lengths in nm, time in s.

The core, at the top: :mod:`.model` (eq 14), :mod:`.inverse` (eqs 8-13), :mod:`.limits`,
:mod:`.operators`, :mod:`.instrument` (the interface every instrument implements, simulated or
real) and :mod:`.tip`. It imports nothing else of the package. Around it, by subsystem:
``identification`` (sensorless), ``sensor`` (the fit with a position sensor),
``positioning``, ``drift``, ``imaging`` and ``drivers`` (backends for real controllers) use
the core and never the simulator; ``virtual_afm`` is the simulator;
``experiments`` runs the paper's experiments on it and alone reads its ground truth; ``io``,
``plotting`` and ``commands`` (the command line) serve them all.
"""

__version__ = "0.1.0"
