"""K PPO members as one batched computation (``learner.BatchedPpoLearner`` over ``update.PopulationPPO``): the engine
of a population (``train.py --seeds``) and of SAPG's leader and followers."""
