"""Off-policy TD3 for many parallel envs, after FastTD3 (``--learner fasttd3``): the learner (``learner``) and its
networks, losses and replay (``update``)."""
