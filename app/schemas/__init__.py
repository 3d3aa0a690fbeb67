"""Pydantic v2 wire models of the v1 API (``api-v1.md``); the learning core never sees them."""
