"""Plots and rerun streams for people to look at."""
