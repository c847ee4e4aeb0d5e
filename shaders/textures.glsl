// Material texture samplers, each with its UV set and KHR_texture_transform matrix; only the
// maps a material uses are declared (HAS_*_MAP defines), so others cost nothing.
#ifndef TEXTURES_GLSL
#define TEXTURES_GLSL
in vec2 v_uv0;
#ifdef HAS_UV1
in vec2 v_uv1;
#endif

#define DECLARE_MAP(name) uniform sampler2D u_##name##_map; uniform mat3 u_##name##_uvm;
#define SAMPLE_MAP(name, uv) texture(u_##name##_map, (u_##name##_uvm * vec3(uv, 1.0)).xy)

#ifdef HAS_BASE_COLOR_MAP
DECLARE_MAP(base_color)
#endif
#ifdef HAS_METALLIC_ROUGHNESS_MAP
DECLARE_MAP(metallic_roughness)
#endif
#ifdef HAS_NORMAL_MAP
DECLARE_MAP(normal)
#endif
#ifdef HAS_OCCLUSION_MAP
DECLARE_MAP(occlusion)
#endif
#ifdef HAS_EMISSIVE_MAP
DECLARE_MAP(emissive)
#endif
#ifdef HAS_SPECULAR_MAP
DECLARE_MAP(specular)
#endif
#ifdef HAS_SPECULAR_COLOR_MAP
DECLARE_MAP(specular_color)
#endif
#ifdef HAS_CLEARCOAT_MAP
DECLARE_MAP(clearcoat)
#endif
#ifdef HAS_CLEARCOAT_ROUGHNESS_MAP
DECLARE_MAP(clearcoat_roughness)
#endif
#ifdef HAS_CLEARCOAT_NORMAL_MAP
DECLARE_MAP(clearcoat_normal)
#endif
#ifdef HAS_SHEEN_COLOR_MAP
DECLARE_MAP(sheen_color)
#endif
#ifdef HAS_SHEEN_ROUGHNESS_MAP
DECLARE_MAP(sheen_roughness)
#endif
#ifdef HAS_IRIDESCENCE_MAP
DECLARE_MAP(iridescence)
#endif
#ifdef HAS_IRIDESCENCE_THICKNESS_MAP
DECLARE_MAP(iridescence_thickness)
#endif
#ifdef HAS_ANISOTROPY_MAP
DECLARE_MAP(anisotropy)
#endif
#ifdef HAS_DIFFUSE_TRANSMISSION_MAP
DECLARE_MAP(diffuse_transmission)
#endif
#ifdef HAS_DIFFUSE_TRANSMISSION_COLOR_MAP
DECLARE_MAP(diffuse_transmission_color)
#endif
#ifdef HAS_TRANSMISSION_MAP
DECLARE_MAP(transmission)
#endif
#ifdef HAS_THICKNESS_MAP
DECLARE_MAP(thickness)
#endif
#endif
