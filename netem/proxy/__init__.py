"""The proxy: each packet of a run through its link, in lockstep or realtime, and its records."""
