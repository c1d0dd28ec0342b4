"""``--learner ppo``: rsl-rl's PPO on the env's transitions (``learner.PpoLearner``), by default with its update free
of host syncs (``sync_free.SyncFreePPO``)."""
