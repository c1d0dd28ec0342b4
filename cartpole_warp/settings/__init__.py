"""The settings: the env's config schemas and their checks (``config``), the agent's (``agent``), presets
(``presets``), the files shipped with the package (``files``) and deprecated names (``deprecation``)."""
