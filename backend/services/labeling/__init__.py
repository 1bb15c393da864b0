"""The annotators' work: submissions, the set of samples queued for annotation, the labelling guidelines."""
