"""Typed client for the Attune v1 API."""
