"""End-to-end flows through the API: a batch posted, stored, associated by a worker and served
back (in process or against a live server); each module checks a flow, not one module."""
