"""Shipped graphs and example scenes (package data)."""
