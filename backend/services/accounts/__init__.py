"""Accounts: users and their roles, password hashing and tokens, the per-process token cache, login limits."""
