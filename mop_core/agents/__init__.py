"""Agents: TD3 (the behaviour policies), PBRL (the teachers, also as a vectorised group of runs) and the
naive multi-task PBRL baseline."""
