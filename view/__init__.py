"""demo.view."""
