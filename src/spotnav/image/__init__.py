"""The image: spots found in a frame and the sub-pixel edge read along rays."""
