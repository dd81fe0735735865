"""Example learned ssga plugin: a tiny per-pixel classifier, averaged over each region."""
