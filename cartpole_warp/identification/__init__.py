"""Physical parameters from recordings: ``sysid`` fits a task's physics to a recorded trajectory by gradients through
the simulator, predicts whole episodes with the fit and writes it as a preset (its programs: ``tools.sysid``,
``tools.multiarm``); ``chain`` says what a free swing of a chain of arms can tell and what a fit leaves to the
stage."""
