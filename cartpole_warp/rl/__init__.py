"""Training with rsl-rl, for any registered task. Nothing here imports a task module: a task comes from the registry
by name. The modules, by what they hold:

- the loop and a run's books: ``runner`` (``TaskRunner``: one run's loop over a learner), ``training`` (a solo run end
  to end: build, Ctrl-C, the run folder's end), ``population_training`` (a population's run), ``population``
  (``--seeds``' members, their evaluation), ``evaluations`` (when one is due, where it runs), ``progress`` (the console
  line and metrics), ``runs`` (run folders, checkpoints, ``summary.json``), ``curve`` (the learning curve), ``video``
  (``--video``'s clips);
- the learners, a folder each in ``learners`` (the ``Learner`` seam and the lookup by name): ``ppo`` (rsl-rl's PPO and
  the sync-free update), ``batched_ppo`` (K members as one batched PPO), ``sapg`` (a leader and its followers, on
  ``batched_ppo``), ``shac`` (analytic policy gradients through the simulator, SHAC);
- networks and rsl-rl's dict: ``policies`` (``train_cfg``, checkpoints, exports), ``image_model`` (the CNN);
- infrastructure: ``config`` (``TrainConfig``), ``distributed`` (torchrun).
"""
