"""Values the schemas' examples share."""

EXAMPLE_ID = "0d5f8a4e-0b8e-4c39-9d47-5a1b2c3d4e5f"
