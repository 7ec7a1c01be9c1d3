"""ringlight.app."""
