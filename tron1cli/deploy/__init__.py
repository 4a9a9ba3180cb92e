"""Sim-to-sim deployment: an exported policy driven the way the robot's onboard computer runs it."""
