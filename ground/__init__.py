"""Ground side: the ``smcpilot`` command line, the paper reproduction, benchmarks, and (later)
the ground-station client and mission tests."""
