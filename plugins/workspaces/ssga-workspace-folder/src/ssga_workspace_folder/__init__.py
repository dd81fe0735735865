"""A folder of captured images with poses, as an ssga workspace."""
