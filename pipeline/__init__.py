"""pipeline: the ``lumigraph`` command, its stages (one folder of artifacts each), the report,
the studies and the exports. The only layer that knows the artifact layout; imports every other."""

__version__ = "0.1.0"
