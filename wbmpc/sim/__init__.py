"""Simulation: the rigid-contact and PyBullet plants, sensing, disturbances, the closed loop."""
