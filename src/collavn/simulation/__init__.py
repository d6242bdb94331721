"""Simulation: differential-drive kinematics with collisions, and the batched world."""
