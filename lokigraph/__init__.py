"""lokigraph: open simulation framework for character effects."""
__version__ = "0.1.0"
