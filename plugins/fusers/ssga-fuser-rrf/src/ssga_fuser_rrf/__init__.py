"""Reciprocal-rank fusion for ssga."""
