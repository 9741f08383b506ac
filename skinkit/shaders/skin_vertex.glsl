#version 430
// skinkit: animation-space skinning in a vertex shader, GLSL 4.3. SPDX-License-Identifier: GPL-3.0-or-later
//
// Per-vertex attribute layout (agreed with skinkit's glTF export, which writes these accessors):
//   JOINTS_0       uvec4  the bone indices of influence slots 0-3
//   _SKINKIT_JOINTS_1 vec4 the bone indices of slots 4-7, whole numbers as floats (only with SKINKIT_SLOTS 8;
//                         Blender's glTF exporter writes JOINTS_1 only for more than 4 LBS weights, never here)
//   _SKINKIT_P_<j> vec4   for slot j = 0 .. SKINKIT_SLOTS - 1, the animation-space 4-vector p_j of that influence
//                         in its bone's frame (VEC4 float); unused slots are zero vectors (any joint index)
//   _SKINKIT_DP_<j> vec4  only with SKINKIT_GEOMORPH: dp_j = p_j^{l+1} - p_j^l on the common influence set (eq. 7.1)
// Bone matrices: a shader storage buffer at binding 4 of 3 vec4 per bone, the top three rows of G_j (row-major 3x4,
// model space, bone 0 the root). The skinned model-space position is
//   v = sum_j G[joint_j] (p_j + u_lod_fraction dp_j)        (dp = 0 without SKINKIT_GEOMORPH)
// Unlike linear blend skinning there are no weights: each p_j carries its weight in its fourth component, and the
// fourth components of a vertex's p_j sum to 1. The host prepends `#define SKINKIT_SLOTS 4` (or 8) and optionally
// `#define SKINKIT_GEOMORPH` (4 slots only: 8 would exceed 16 attributes) after the #version line
// (skinkit.shaders.source does). Attributes are bound by name (no fixed locations).
#ifndef SKINKIT_SLOTS
#define SKINKIT_SLOTS 8
#endif
#if defined(SKINKIT_GEOMORPH) && SKINKIT_SLOTS > 4
// 2 joint + 8 p + 8 dp attributes exceed the 16 vertex attributes OpenGL guarantees: geomorph 8 slots in skin_compute.
#error "SKINKIT_GEOMORPH needs SKINKIT_SLOTS 4"
#endif

in uvec4 JOINTS_0;
in vec4 _SKINKIT_P_0;
in vec4 _SKINKIT_P_1;
in vec4 _SKINKIT_P_2;
in vec4 _SKINKIT_P_3;
#if SKINKIT_SLOTS > 4
in vec4 _SKINKIT_JOINTS_1;
in vec4 _SKINKIT_P_4;
in vec4 _SKINKIT_P_5;
in vec4 _SKINKIT_P_6;
in vec4 _SKINKIT_P_7;
#endif
#ifdef SKINKIT_GEOMORPH
in vec4 _SKINKIT_DP_0;
in vec4 _SKINKIT_DP_1;
in vec4 _SKINKIT_DP_2;
in vec4 _SKINKIT_DP_3;
#if SKINKIT_SLOTS > 4
in vec4 _SKINKIT_DP_4;
in vec4 _SKINKIT_DP_5;
in vec4 _SKINKIT_DP_6;
in vec4 _SKINKIT_DP_7;
#endif
uniform float u_lod_fraction;
#endif

layout(std430, binding = 4) readonly buffer Matrices { vec4 matrices[]; };

uniform mat4 u_view_projection;

out vec3 skinned_position; // model space, for transform feedback or the fragment stage

vec3 transformed(uint joint, vec4 p)
{
    int row = 3 * int(joint);
    return vec3(dot(matrices[row], p), dot(matrices[row + 1], p), dot(matrices[row + 2], p));
}

void main()
{
#if SKINKIT_SLOTS > 4
    uvec4 JOINTS_1 = uvec4(_SKINKIT_JOINTS_1 + 0.5);  // the accessor holds whole numbers as floats
#endif
#ifdef SKINKIT_GEOMORPH
    float f = u_lod_fraction;
    vec3 v = transformed(JOINTS_0.x, _SKINKIT_P_0 + f * _SKINKIT_DP_0) + transformed(JOINTS_0.y, _SKINKIT_P_1 + f * _SKINKIT_DP_1) +
             transformed(JOINTS_0.z, _SKINKIT_P_2 + f * _SKINKIT_DP_2) + transformed(JOINTS_0.w, _SKINKIT_P_3 + f * _SKINKIT_DP_3);
#if SKINKIT_SLOTS > 4
    v += transformed(JOINTS_1.x, _SKINKIT_P_4 + f * _SKINKIT_DP_4) + transformed(JOINTS_1.y, _SKINKIT_P_5 + f * _SKINKIT_DP_5) +
         transformed(JOINTS_1.z, _SKINKIT_P_6 + f * _SKINKIT_DP_6) + transformed(JOINTS_1.w, _SKINKIT_P_7 + f * _SKINKIT_DP_7);
#endif
#else
    vec3 v = transformed(JOINTS_0.x, _SKINKIT_P_0) + transformed(JOINTS_0.y, _SKINKIT_P_1) +
             transformed(JOINTS_0.z, _SKINKIT_P_2) + transformed(JOINTS_0.w, _SKINKIT_P_3);
#if SKINKIT_SLOTS > 4
    v += transformed(JOINTS_1.x, _SKINKIT_P_4) + transformed(JOINTS_1.y, _SKINKIT_P_5) +
         transformed(JOINTS_1.z, _SKINKIT_P_6) + transformed(JOINTS_1.w, _SKINKIT_P_7);
#endif
#endif
    skinned_position = v;
    gl_Position = u_view_projection * vec4(v, 1.0);
}
