"""Deployment: the compose file, credentials and access control."""
