"""Agents: TD3 (behaviour policies); PBRL teachers and the naive multi-task baseline follow."""
