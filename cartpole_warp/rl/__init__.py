"""Training with rsl-rl, for any registered task. Nothing here imports a task module: a task comes from the registry
by name. The modules, by what they hold:

- the loop and a run's books: ``training`` (a training end to end, of one run or a population's: build, Ctrl-C, the
  run folders' end), ``loop`` (``TrainingLoop``: the one loop, of K >= 1 runs over a learner), ``record``
  (``RunRecord``: one run's books), ``population`` (``--seeds``' members, the population's files), ``evaluations``
  (when one is due, where it runs: K members' at once), ``progress`` (the console line and metrics), ``runs`` (run
  folders, checkpoints, ``summary.json``), ``curve`` (the learning curve), ``video`` (``--video``'s clips);
- the learners, a folder each in ``learners`` (the ``Learner`` seam and the lookup by name): ``ppo`` (rsl-rl's PPO and
  the sync-free update), ``batched_ppo`` (K members as one batched PPO), ``sapg`` (a leader and its followers, on
  ``batched_ppo``), ``shac`` (analytic policy gradients through the simulator, SHAC);
- networks and rsl-rl's dict: ``policies`` (``train_cfg``, checkpoints, exports), ``image_model`` (the CNN);
- infrastructure: ``config`` (``TrainConfig``), ``distributed`` (torchrun).
"""
