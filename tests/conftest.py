"""Test-wide settings: Hypothesis without deadlines (numba compiles on first call)."""

from hypothesis import settings

settings.register_profile("piezocomp", deadline=None, max_examples=60)
settings.load_profile("piezocomp")
