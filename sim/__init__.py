"""The bundled simulated vehicle: rigid-body quadrotor physics, wind, sensors and firmware loops."""
