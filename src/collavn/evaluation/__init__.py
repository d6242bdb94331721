"""Evaluation: policies without learning, the runner, and the evaluate/viz/demo commands."""
