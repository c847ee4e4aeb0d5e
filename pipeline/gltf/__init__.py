"""glTF 2.0 ingest: the reader (container, accessors, primitives, node graph), compressed
payload decoders, the Khronos material extensions, skins and morphs, spec-gloss conversion.

May import `core` and the rest of `pipeline`; nothing in `renderer` or `service`."""
