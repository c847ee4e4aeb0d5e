"""glTF 2.0 ingest, by concern:
- `reader`: `load(path, limits, root)`, the extensions we read, and the scene assembly;
- `accessors`: the container (GLB chunks), checked JSON access (`Document`), buffers, views
  and accessors; `decode`: meshopt and Draco payloads;
- `primitives`: primitives into meshes (modes, Draco, morph targets, skins, thickened wire);
  `skin`: the morph and skinning arithmetic;
- `materials`: textures, samplers and materials with the Khronos extensions; `specgloss`: the
  specular-glossiness conversion; `variants`: KHR_materials_variants;
- `nodes`: the node graph, instancing, cameras and lights.

May import `core` and the rest of `pipeline`; nothing in `renderer` or `service`."""
