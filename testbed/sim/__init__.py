"""The simulators: the model in one process, one seed at a time or a batch of seeds at once."""
