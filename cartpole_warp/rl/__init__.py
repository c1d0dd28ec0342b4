"""Training with rsl-rl: the configuration (``config``), the runner (``runner``), one run end to end (``training``),
run folders (``runs``), episode statistics and "solved" (``metrics``), the learning curve (``curve``) and policy
rollouts (``rollout``)."""
