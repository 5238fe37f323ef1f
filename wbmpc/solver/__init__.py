"""Solving: generated and compiled NLP functions and their cache, the deployment artefact, BLASFEO."""
