"""Fitting a rig to a model's skeleton, on plain rig values (no USD here): naming
conventions and the joint mapping, the retargeter through reference poses, the per-rig
model map, the own-rig pass-through for interpolation."""
