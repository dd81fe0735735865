"""SynSin-style learned view synthesis for ssga: depth and features from one image, a z-buffered soft point splat, a refinement network."""
