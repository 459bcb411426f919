"""Exchange formats for animated faces."""
