"""What a run leaves: the MCAP writer, the channels' schemas, the display names."""
