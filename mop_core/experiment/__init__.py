"""The study as data: its params' grid and checks, the kinds of run and student variants, the
catalogue of every run, and the cost plan."""
