"""What every learner shares: networks and vectorised ensembles, the training schedule and loop,
per-step metrics, process settings, gradient conflict."""
