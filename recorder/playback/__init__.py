"""A recording played back over Zenoh, at its pace or faster."""
