"""Pong (§7.10, Table 7.3)."""
