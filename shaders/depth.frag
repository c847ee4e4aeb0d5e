#version 430
// Light shadow maps (renderer/raster/light_shadows.py): depth only, no colour.
void main() {}
