"""The paper's experiments on the virtual AFM, and everything that reads its ground truth.

One module per figure or table (:mod:`.table1`, :mod:`.fig8`, :mod:`.fig9`, :mod:`.fig10`,
:mod:`.drift_session`), the methods compared (:mod:`.methods`), the run of them all
(:mod:`.reproduce`) and its report (:mod:`.report`); the experiments that make sense on a
real sample, run in turn on one instrument with measured errors only (:mod:`.on_instrument`).
Identification on the virtual lab with its grating (:mod:`.virtual_identification`) and
scoring against the simulator's truth (:mod:`.scoring`, :mod:`.truth`) live here because they
read what only the simulator knows.

May import every other subpackage; nothing outside ``commands`` imports it.
"""
