"""Solving: generated and compiled NLP functions and their cache, the deployment artefact, BLASFEO."""

from wbmpc.solver import blasfeo

# The process's BLASFEO is chosen on the first import of this subpackage, before casadi opens its Fatrop
# plugin: every wbmpc path to a Fatrop solver goes through here (wbmpc.control.mpc imports it).
blasfeo.activate()
