"""Gradients through the simulator: differentiable rollouts of a state task (``rollout.DifferentiableRollout``)."""
