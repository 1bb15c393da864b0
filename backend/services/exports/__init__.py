"""The dataset's records for exports and the FreiHAND export as a job."""
