"""mavadrc: disturbance-rejecting offboard control (ADRC, linear ADRC, PD) for multirotors."""

__version__ = "0.1.0"
