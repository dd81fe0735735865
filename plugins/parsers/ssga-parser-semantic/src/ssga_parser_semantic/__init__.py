"""Ground-truth semantic ids as ssga scene-graph parts: an oracle parser."""
