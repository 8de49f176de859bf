"""Unitree AlienGo: MJCF model and the constants it was written from."""
