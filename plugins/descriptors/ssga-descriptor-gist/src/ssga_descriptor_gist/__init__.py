"""ssga-descriptor-gist: where the edges run and where the colours lie, on a coarse grid."""
