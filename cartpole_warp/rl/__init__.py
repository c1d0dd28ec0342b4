"""Training with rsl-rl, for any registered task: the configuration (``config``), the runner (``runner``), the
sync-free PPO (``ppo``), one run end to end (``training``), several GPUs (``distributed``), run folders (``runs``) and
the learning curve (``curve``). Nothing here imports a task module: a task comes from the registry by name."""
