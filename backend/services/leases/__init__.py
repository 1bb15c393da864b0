"""The work queues shared by annotate and review: leases (queues), prefetch, drafts, the checks of clicks and
masks a draft and a submission share, and an annotator's flags (no hand, skip, failed fit)."""
