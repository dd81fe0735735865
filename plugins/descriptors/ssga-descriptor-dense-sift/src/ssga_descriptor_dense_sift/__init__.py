"""Dense SIFT on Patch-NetVLAD's patch grid, pooled into bag-of-words node features (an ssga descriptor)."""
