"""Kinematic trees (URDF/xacro), forward kinematics (NumPy and torch), trajectories, visual geometry,
workspace. Submodules import on use: the torch FK (``fk_torch``) is never imported by the NumPy path."""
