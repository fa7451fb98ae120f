"""Collision pipeline: broad phase, narrow phase, response."""
