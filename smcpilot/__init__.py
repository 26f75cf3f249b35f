"""smcpilot: shared pure pieces of the SITL flight controller.

This package holds what both processes need and nothing that does I/O on its own:

- :mod:`smcpilot.vehicle` -- vehicle parameters (units in the names) and their defaults;
- :mod:`smcpilot.model` -- the paper's corrected quadrotor model (eqs. 10, 11, 13, 14), the
  mixer and its inverse, and the time derivatives of the model terms the control law needs;
- :mod:`smcpilot.errors` -- the project's exception classes.

The flight controller (:mod:`fc`) and the simulator bridge (:mod:`sim_bridge`) both import from
here and never from each other.
"""

__version__ = "0.1.0"
