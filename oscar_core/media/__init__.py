"""Video files: reading, writing, encoder options."""
