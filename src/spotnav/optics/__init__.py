"""Optics and camera: projection, the light's edge, the camera's blur and noise, and the renderer."""
