"""Training the world model: the clip format, window and source samplers, the rectified-flow loop, checkpoints."""
