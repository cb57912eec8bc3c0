"""piezocomp: sensorless compensation of piezo scanner creep and hysteresis.

Implements Mokaberi & Requicha, "Compensation of Scanner Creep and Hysteresis for AFM
Nanomanipulation", IEEE T-ASE 5(2), 2008. Lengths in nm, time in s.

The core, at the top: :mod:`.model` (eq 14), :mod:`.inverse` (eqs 8-13), :mod:`.limits` (travel
range and slew), :mod:`.operators`, :mod:`.instrument` (the interface every instrument
implements, simulated or real) and :mod:`.tip` (the tip's shape, which images and pushes depend
on); beside it :mod:`.bench` (the kernels' throughput, ``piezocomp bench``) and two private
helpers every subpackage may use, ``_atomic`` (files written atomically) and ``_validation``
(input checks). The core imports nothing else of the package but these two. Around it, by
subsystem: ``identification`` (sensorless), ``sensor`` (the fit with a position sensor),
``positioning``, ``drift``, ``imaging`` and ``drivers`` (backends for real controllers) use the
core and never the simulator (the one exception: ``drivers``' Nanonis emulator, which serves
the simulator over the Nanonis protocol); ``virtual_afm`` is the simulator; ``experiments``
runs the paper's experiments, on it or on a real instrument, and alone reads the simulator's
ground truth; ``io``, ``plotting`` and ``commands`` (the command line) serve them all;
``testing`` holds plain-Python oracles of the kernels.
"""

__version__ = "0.1.0"
