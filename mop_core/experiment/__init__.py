"""The study as data: its params' grid and checks, the kinds of run and student variants, the
catalogue of every run (the cost plan is mop_core/plan.py)."""
