"""Borda-count and mean-probability fusion for ssga."""
