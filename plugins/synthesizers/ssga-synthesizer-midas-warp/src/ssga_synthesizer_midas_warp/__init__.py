"""midas-warp view synthesis for ssga: MiDaS depth from RGB alone, calibrated to metres, then depth-warp's forward warp."""
