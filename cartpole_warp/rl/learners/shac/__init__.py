"""``--learner apg``: short-horizon analytic policy gradients through the simulator with a critic (SHAC:
``learner.ApgLearner``)."""
