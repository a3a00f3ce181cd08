"""mptrack: position tracking of mobile terminals from cellular and positioning measurements."""

__version__ = "0.1.0"
__all__ = ["__version__"]
