"""Testing aids shipped with the package: plain-Python oracles of the numba kernels.

They are used by the test suite and by ``piezocomp bench`` (which times the reference
against the kernels in the same run).
"""
