"""A procedural world small enough to train the whole OSCAR pipeline on a CPU."""
