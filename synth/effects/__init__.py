"""The optional effects: their description, the camera side (defocus, noise, quantisation) and global illumination."""
