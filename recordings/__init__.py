"""Bundled sample missions, found through the package (`importlib.resources`): `sample.mcap` is the demo's input."""
