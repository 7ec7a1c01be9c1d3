"""ringlight.widgets."""
