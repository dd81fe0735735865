"""ssga-descriptor-depth-layout: the room's shape, read from one RGB image by a depth network."""
