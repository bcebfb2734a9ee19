"""Testing helpers for oscar and for plugin authors: golden-image comparison."""

from .golden import assert_matches_golden, compare_images, read_png, write_png

__all__ = ["assert_matches_golden", "compare_images", "read_png", "write_png"]
