"""Job rows and their hand-off to the workers, and what the end of a job means for its sample (fit_samples) and
its round (round_failure)."""
