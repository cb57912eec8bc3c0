"""The paper's experiments, and everything that reads the virtual AFM's ground truth.

One module per figure or table (:mod:`.table1`, :mod:`.fig8`, :mod:`.fig9`, :mod:`.fig10`,
:mod:`.drift_session`), each an experiment of :mod:`.contract` (``NAME``, ``plan``,
``run_trial``, ``summarise``): a new experiment is a new module with these four names, added
to the tuple :mod:`.reproduce` loops over, its section of ``results.json`` typed in
:mod:`.results`, its rows in :mod:`.report` and its figure in
:mod:`piezocomp.plotting.experiments`. Also the methods compared (:mod:`.methods`), the
trials run in parallel (:mod:`.parallel`), the run of them all (:mod:`.reproduce`), its
report (:mod:`.report`) and the figures over samples (:mod:`.samples`). On a real instrument
the experiments that make sense on a real sample run in turn with measured errors only
(:mod:`.on_instrument`, which reads no truth; a new experiment that makes sense on a real sample
is added to its ``EXPERIMENTS`` too).
Identification on the virtual lab with its grating (:mod:`.virtual_identification`) and
scoring against the simulator's truth (:mod:`.scoring`, :mod:`.truth`) live here because they
read what only the simulator knows.

May import every other subpackage; nothing outside ``commands`` imports it.
"""
