"""The setup: the eye, the instrument's light and the camera, read from a TOML file and checked."""
