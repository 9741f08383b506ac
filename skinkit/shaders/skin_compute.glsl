#version 430
// skinkit: geomorphing animation-space skinning, GLSL 4.3 compute shader (Merry 2007, section 7.4, algorithm 1 on
// the GPU). SPDX-License-Identifier: GPL-3.0-or-later
//
// The same data layout as the C runtime (sk_runtime_skin in csrc/skinkit.h), in shader storage buffers:
//   offsets          int   vertex_count + 1   CSR over every mesh's vertices (the pack)
//   bones            int   influence_count
//   morph_positions  vec4  2 per influence    p_k, then dp_k (p^{l+1} - p^l on the common influence set)
//   morph_tangents   vec4  4 per influence    tangent 0 (p, dp), tangent 1 (p, dp); only read with u_tangents
//   matrices         vec4  3 per bone per instance: the top three rows of G_j (row-major 3x4)
//   instances        ivec4 per instance: (first pack vertex of its mesh, its vertex count, its first output vertex, 0)
//   fractions        float per instance: the geomorph fraction f = l - floor(l)
//   outputs          float 3 per output vertex, for positions and both tangents
// Dispatch (ceil(max vertex count / 64), instance_count, 1) work groups: x walks an instance's vertices, y the
// instances. Each output is sum_k G_{bones[k]} (p_k + f dp_k); an out-of-range bone index contributes nothing.
layout(local_size_x = 64) in;

layout(std430, binding = 0) readonly buffer Offsets { int offsets[]; };
layout(std430, binding = 1) readonly buffer Bones { int bones[]; };
layout(std430, binding = 2) readonly buffer MorphPositions { vec4 morph_positions[]; };
layout(std430, binding = 3) readonly buffer MorphTangents { vec4 morph_tangents[]; };
layout(std430, binding = 4) readonly buffer Matrices { vec4 matrices[]; };
layout(std430, binding = 5) readonly buffer Instances { ivec4 instances[]; };
layout(std430, binding = 6) readonly buffer Fractions { float fractions[]; };
layout(std430, binding = 7) writeonly buffer OutPositions { float out_positions[]; };
layout(std430, binding = 8) writeonly buffer OutTangent0 { float out_tangent_0[]; };
layout(std430, binding = 9) writeonly buffer OutTangent1 { float out_tangent_1[]; };

uniform int u_bone_count;
uniform bool u_tangents;

// Row r of bone j's 3x4 matrix in instance i.
vec4 bone_row(int instance, int bone, int row)
{
    return matrices[3 * (instance * u_bone_count + bone) + row];
}

// sum over the vertex's influences of G (p + f dp); stream 0 positions, 1 and 2 the tangents.
vec3 skin(int instance, int vertex, float f, int stream)
{
    vec3 sum = vec3(0.0);
    for (int k = offsets[vertex]; k < offsets[vertex + 1]; ++k) {
        int bone = bones[k];
        if (bone < 0 || bone >= u_bone_count)
            continue;
        vec4 q;
        if (stream == 0)
            q = morph_positions[2 * k] + f * morph_positions[2 * k + 1];
        else
            q = morph_tangents[4 * k + 2 * (stream - 1)] + f * morph_tangents[4 * k + 2 * (stream - 1) + 1];
        sum += vec3(dot(bone_row(instance, bone, 0), q), dot(bone_row(instance, bone, 1), q),
                    dot(bone_row(instance, bone, 2), q));
    }
    return sum;
}

void write3(int stream, int target, vec3 v)
{
    if (stream == 0) {
        out_positions[3 * target] = v.x; out_positions[3 * target + 1] = v.y; out_positions[3 * target + 2] = v.z;
    } else if (stream == 1) {
        out_tangent_0[3 * target] = v.x; out_tangent_0[3 * target + 1] = v.y; out_tangent_0[3 * target + 2] = v.z;
    } else {
        out_tangent_1[3 * target] = v.x; out_tangent_1[3 * target + 1] = v.y; out_tangent_1[3 * target + 2] = v.z;
    }
}

void main()
{
    int instance = int(gl_WorkGroupID.y);
    ivec4 range = instances[instance];
    int local = int(gl_GlobalInvocationID.x);
    if (local >= range.y)
        return;
    int vertex = range.x + local, target = range.z + local;
    float f = fractions[instance];
    int streams = u_tangents ? 3 : 1;
    for (int stream = 0; stream < streams; ++stream)
        write3(stream, target, skin(instance, vertex, f, stream));
}
