"""Interior vectors for refractive meshes (Wyman two-pass refraction): rays cast with
Embree through triangles paired into quads.

May import `core` and the rest of `pipeline`."""
