"""Robot models: URDF/SRDF loading with checks, locked joints, limits, static equilibrium."""
