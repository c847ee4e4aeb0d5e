"""The headless OpenGL context, one per process, and the programs compiled in it.

Shared by the two layers that draw: `pipeline` (environment prefiltering at bake) and
`renderer`. Imports nothing of ours but `shaders`."""
