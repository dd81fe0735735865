"""CNN-RRF (an ssga descriptor): a VGG place classifier whose class ranking of the image and of each region is the node feature."""
