"""Private helpers shared by every layer: atomic writes, logging, stages and their fingerprints,
worker pools, threads, devices, optional dependencies. Nothing here is public API."""
