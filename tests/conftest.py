"""Test-wide settings.

Hypothesis runs without deadlines (numba compiles on first call). On CI (``CI`` set) the
examples are derandomised, so a run is reproducible and a landing is never decided by a
lucky draw; local runs keep exploring new examples.
"""

import os

from hypothesis import settings

settings.register_profile("piezocomp", deadline=None, max_examples=60, print_blob=True)
settings.register_profile("ci", parent=settings.get_profile("piezocomp"), derandomize=True)
settings.load_profile("ci" if os.environ.get("CI") else "piezocomp")
