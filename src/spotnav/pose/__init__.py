"""The pose: the thesis's and the precise methods, the one cone fit, and the checks of a fit."""
