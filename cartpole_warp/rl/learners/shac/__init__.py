"""``--learner shac`` (``apg`` until ``settings.deprecation.REMOVED_IN``): short-horizon analytic policy gradients
through the simulator, with a critic (SHAC: ``learner.ShacLearner``)."""
