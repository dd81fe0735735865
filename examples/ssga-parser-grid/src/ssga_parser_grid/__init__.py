"""A regular-grid scene parser for ssga (an example plugin)."""
