"""demo.interop."""
