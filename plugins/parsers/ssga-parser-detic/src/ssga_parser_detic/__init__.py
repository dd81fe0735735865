"""Detic instance detections as ssga scene-graph parts (the paper's P-DE parser)."""
