"""The plugin contract: hook specs, the embodiment and reader contracts, the skeleton spec, the registry."""
