"""Fusion of ssga variants learned on the validation views (stacking)."""
