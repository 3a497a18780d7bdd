"""roadlink: group anonymous roadside detections into one row per vehicle."""

__version__ = "0.1.0"
