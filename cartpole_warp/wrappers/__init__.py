"""Thin translations of any task's ``BatchedEnv`` to other libraries' interfaces: ``rsl_rl`` (rsl-rl ``VecEnv``),
``gymnasium`` (``gymnasium.Env`` and ``VectorEnv``, registered ids) and ``sb3`` (Stable-Baselines3 ``VecEnv``). Each
module imports its library; import the one you need."""
