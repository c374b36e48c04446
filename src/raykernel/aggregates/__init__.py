"""Acceleration structures: each module builds one kind of aggregate as flat arrays."""
