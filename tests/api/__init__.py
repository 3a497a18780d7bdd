"""Tests of `roadlink.api`, a module per module (`test_<module>.py`, routers and schemas in
the same folders as in the package), and whole flows through the API in `end_to_end/`.

Pure declarations have no module of their own: `schemas/health.py` (two response models, checked
against the served answers in routers/test_health.py) and `schemas/examples.py` (one constant)."""
