"""Plants the simulator bridge can integrate."""
