"""Post-processing applied after an in-betweener (keys exact, root path, foot contact)."""
