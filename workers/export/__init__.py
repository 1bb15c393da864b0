"""Dataset exports: FreiHAND's layout (`freihand.py`), fitted meshes (`meshes.py`), and the plain records
the server hands them (`records.py`, importable without torch). See docs/evaluation.md."""
