"""Acceptance criteria for a user's CI: named checks of a run's figures against limits (`criteria`, one module per
kind in `kinds`), the JUnit XML of a command (`junit`), and the options the run commands share (`cli`)."""
