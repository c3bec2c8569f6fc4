"""Tutorial (to be written): IKD to hit a pose, then a USD point cache.

Adds pose, subset, velocity and end-effector constraints to a shot, solves IKD so the KD states meet them, checks
the result independently and writes the corrected trajectory as a USD point cache.
"""
