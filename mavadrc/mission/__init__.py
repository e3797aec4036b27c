"""Missions, reference trajectories and the identification manoeuvres."""
