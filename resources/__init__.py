"""ringlight.resources."""
