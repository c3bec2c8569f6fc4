"""Tutorial (to be written): the floppy hat, its KD and its modal window.

Puts the procedural hat on the default head as tetrahedral FEM, simulates its KD states along a head animation,
and derives the KD window from the hat's first vibration mode (the modal window report).
"""
