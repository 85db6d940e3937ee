"""Line-map (DLG) vector layers from a classified cloud."""
