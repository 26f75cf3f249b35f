"""Reproduction of the paper's simulation (§VI, spec §5): scenario, metrics, figures, report."""
