"""The admin console in headless Chromium against a live service."""
