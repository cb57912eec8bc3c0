"""Stage 2, the loop (Section IV, eqs 21-23): the steady cycles of part A give the symmetric
loop ``f_a`` and the height profile ``h(y)``; the calibration cycles give their own loop, onto
which the reference stage maps the models (:mod:`piezocomp.identification.reference.frames`).

- :mod:`.config`: its settings, :class:`~.config.LoopConfig` (the degree of eq 23);
- :mod:`.symmetric`: the symmetric loop of eq (23) from paired peaks;
- :mod:`.pi_branch`: a Prandtl-Ishlinskii branch through the calibration loop;
- :mod:`.profile`: the topography ``h(y)`` along the line;
- :mod:`.fit`: the loop and ``h`` of a record, :func:`~.fit.estimate_loop`.

Reads the acquisition's records; imports no later stage (the compiled ``h(y)`` it shares
with the RLS is :mod:`piezocomp.identification._rls_kernel`).
"""
