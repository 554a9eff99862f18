"""Foxglove, live: the WebSocket server, the scene, the log, the layout."""
