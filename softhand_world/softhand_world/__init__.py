"""softhand_world."""
