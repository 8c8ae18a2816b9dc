"""softhand_tracking."""
