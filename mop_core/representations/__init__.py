"""What the students' hidden layers share across task ids (thesis 6.2): Kendall tau, CKA, similarity and
the shared_computation stage."""
