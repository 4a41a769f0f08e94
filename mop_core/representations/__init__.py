"""How alike two sets of hidden activations are (thesis 6.2): batched Kendall tau-a/tau-b, linear CKA,
Procrustes, debiased CKA, task selectivity. The shared_computation stage's work over the students is
mop_core.shared_computation and mop_core.shared_study."""
