"""Tutorial (to be written): KD of a keyed face animation.

Keys a few blend shapes and a head turn on the default rig, builds the kinematic trajectory, picks the KD window
automatically, simulates the KD state of every frame (and of one frame on its own, as when scrubbing) and compares
it with the full simulation from the shot start.
"""
