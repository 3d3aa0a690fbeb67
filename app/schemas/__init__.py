"""Pydantic v2 wire models of the v1 API (``docs/api.md``); the learning core never sees them."""
