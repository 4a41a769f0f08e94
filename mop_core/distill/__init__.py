"""Policy distillation (thesis 4.2, 5.1.3): the student, its losses, cached teacher targets, the
gradient step (``distiller``) and a whole distillation run (``run``)."""
