"""Simulator bridge: quadrotor plants (the paper's model and a realistic rigid body), their
disturbances, and the process that integrates them and talks MAVLink to the flight controller."""
