"""Simulated annotators and reviewers that use the real HTTP API, driven by a synthetic capture's ground
truth, and the bootstrap simulation D_0 ... D_n built on them (docs/evaluation.md).

Why here (backend/, not workers/): the simulated people are clients of the web side's API, part of its
test and benchmark tooling, not compute; the API process never imports this package, and torch (to pose
a fit and measure its true error) is imported only when a reviewer first needs it.
"""
