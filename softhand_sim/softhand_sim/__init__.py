"""softhand_sim."""
