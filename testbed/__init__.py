"""The ``formation`` command, the process launcher, the in-process simulator and experiments."""
