"""Authentication: password hashing, signed tokens, login limits, the first admin, guards."""
