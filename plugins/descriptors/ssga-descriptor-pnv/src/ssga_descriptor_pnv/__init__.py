"""Patch-NetVLAD local features pooled into bag-of-words node features (an ssga descriptor)."""
