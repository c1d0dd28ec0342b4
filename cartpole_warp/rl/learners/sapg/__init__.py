"""``--learner sapg``: a leader PPO policy learning from its followers' blocks of envs too (``learner.SapgLearner``
over ``learner.LeaderFollowerPPO``), built on ``batched_ppo``."""
