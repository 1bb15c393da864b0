"""Manual verification: the reviewer queue by the paper's policy, reviewer decisions, and the heuristic that accepts
fits without a reviewer (verification)."""
