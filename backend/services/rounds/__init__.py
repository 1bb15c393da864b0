"""Bootstrap rounds (launch, cancel, membership) and pre-annotation (round 0 without clicks)."""
