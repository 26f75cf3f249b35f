"""Flight controller: the adaptive PID-SMC and its baselines (:mod:`fc.control`), and the
fixed-rate flight-controller process that talks MAVLink to the simulator bridge."""
