"""``python -m piezocomp``: the same command line as ``piezocomp``."""

from piezocomp.cli import main

raise SystemExit(main())
