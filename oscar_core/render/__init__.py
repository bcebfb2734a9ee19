"""Condition videos: the skeleton rasteriser and its video pipeline, the mesh and capsule conditions,
the condition table, and many-episode rendering."""
