"""demo.convert."""
