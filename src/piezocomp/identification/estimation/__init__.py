"""Stage 3, estimation (Section III.C): the scanner model from the record, its loop and
``h(y)``.

- :mod:`.config`: its settings, :class:`~.config.EstimationConfig` (candidate orders, RLS,
  batch refinement, re-indexing, priors, the order choice) and :class:`~.config.RoundsConfig`
  (the rounds over further lines, with the drift along the line, over the whole record);
- :mod:`.prediction`: the model's prediction of the record's heights;
- :mod:`.parameters`, :mod:`.candidates`: the parameter vector of eq (15) and the candidate
  models (creep spectrum, thresholds);
- :mod:`.rls`: the recursive estimator of eqs (16)-(20);
- :mod:`.batch`, :mod:`.batch_cost`, :mod:`.reparametrisation`, :mod:`.threads`: the batch
  refinement of the same prediction error;
- :mod:`.orders`: the orders chosen on held-out heights;
- :mod:`.problem`: the stage for one axis, :class:`~.problem.EstimationProblem` (what it
  estimates from, the held-out part) and its :meth:`~.problem.EstimationProblem.estimate`;
- :mod:`.chain`: the two chains on the first line, :func:`~.chain.estimate`;
- :mod:`.several_lines`: the chains' ends over every line and over the whole record;
- :mod:`.drift_along_line`, :mod:`.drift_rounds`: the sample's drift along the line during the
  record, estimated with the model and taken out;
- :mod:`.findings`: what a user should read about the estimates.

Reads the acquisition's records and the loop's results; imports no later stage.
"""
