"""Subcommands of the ``piezocomp`` CLI, one module each (see :mod:`piezocomp.cli`)."""
