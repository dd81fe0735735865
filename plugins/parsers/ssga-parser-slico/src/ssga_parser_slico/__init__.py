"""SLICO superpixels as ssga scene-graph parts."""
