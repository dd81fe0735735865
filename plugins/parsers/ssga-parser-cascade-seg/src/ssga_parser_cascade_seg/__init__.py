"""ADE20K scene parsing (CSAIL ResNet-dilated + PPM) as ssga scene-graph parts: the paper's P-SE parser."""
