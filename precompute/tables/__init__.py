"""Precomputed tables on disk: ``cache`` (content-hash keyed, atomic, shared folders) and ``exr_io``."""
