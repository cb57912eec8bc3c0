"""piezocomp: sensorless compensation of piezo scanner creep and hysteresis.

Implements Mokaberi & Requicha, "Compensation of Scanner Creep and Hysteresis for AFM
Nanomanipulation", IEEE T-ASE 5(2), 2008. Lengths in nm, time in s.
"""

__version__ = "0.1.0"
