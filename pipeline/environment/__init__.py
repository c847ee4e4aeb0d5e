"""Environment bake: panoramas loaded (or the studio made in code), cube faces and their
GGX-prefiltered specular chain and irradiance.

May import `core`, `gl` (prefiltering runs as GLSL) and the rest of `pipeline`."""
