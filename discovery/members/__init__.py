"""The set's members calibrated, weighed and mixed into one posterior.

The structure search (:mod:`tvcid.discovery.structure`) leaves a set of structures the
recordings cannot tell apart; this package turns its members into the posterior the report
prints. One module each:

* :mod:`.member_calibration` -- one member's priors (the search's box, widened to hold its fit),
  its ensemble and its MCMC;
* :mod:`.member_evidence` -- a member's evidence, by importance sampling from its draws;
* :mod:`.set_weights` -- the members' weights from their evidence at a common temperature, and
  the structural choices they decide;
* :mod:`.ranking_shares` -- the members' shares read off the ranking's held-out scores, beside the
  weights, and the share of the members the cap leaves uncalibrated;
* :mod:`.set_posterior` -- the members' draws mixed by their weights into one posterior of the
  physical quantities they share.

The stage that runs them over an executor is :mod:`tvcid.set_stage`.
"""
