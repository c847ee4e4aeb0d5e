"""Render workers: the pool of processes (or Ray actors) that each own one headless GL
context, and the protocol the server speaks to them.

May import `core`, `gl`, `pipeline`, `renderer` and the service's settings."""
