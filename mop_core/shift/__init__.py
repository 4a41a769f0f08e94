"""The state distribution shift (thesis 5.2-5.3): composed datasets, shift measures, the state_shift stage's
table and figures."""
