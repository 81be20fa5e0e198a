"""Applications: localize, calibrate, track and evaluate, called by the command line and by tests."""
