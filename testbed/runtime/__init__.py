"""Real processes on one machine: the launcher, process groups, the Zenoh router, the recording service."""
