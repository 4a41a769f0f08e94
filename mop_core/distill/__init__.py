"""Policy distillation (thesis 4.2, 5.1.3): the student, its losses, its config (``config``), cached teacher
targets (``states``), the gradient step (``distiller``), the ranking regulariser (``ranking``), state-shift
corrections and DAgger, a group's evaluation, a whole distillation run (``run``) and its checkpoint read back."""
