"""Pictures of the env: GIF side views (``frames``), recordings of a rollout as GIF and time-sampled USD
(``record``, Newton's ``ViewerUSD``) and Newton's interactive ``ViewerGL`` (``viewer``)."""
