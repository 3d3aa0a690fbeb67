"""What the tests share: fixtures (loaded by ``tests/conftest.py``), live services, the people
who answer the robots, the office mission's names, and the contract's error body.

Modules here import nothing at package level, so that ``office`` stays importable where only
numpy is installed (the learning core's own test run)."""
