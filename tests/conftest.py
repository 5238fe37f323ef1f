"""Shared pytest setup."""

import os

# Headless plotting for tests and for notebooks executed by nbmake.
os.environ["MPLBACKEND"] = "Agg"
