// The liver's inside level at query points (see mod.rs): `InsideField::level` of resecta-plan
// minus ½, one invocation per point, f64, transcribed operation for operation: the point to
// its continuous index, the eight corner bits of its cell from the 4×4×4 bit bricks (0 beyond
// the grid), their trilinear weights multiplied in axis order and summed in corner order.
// Requires SHADER_F64.

// 80 bytes. Mirrors `Params` in mod.rs.
struct Params {
    r0: vec4<f64>,     // row 0 of world → index (xyz), origin.x (w)
    r1: vec4<f64>,     // row 1, origin.y
    r2: vec4<f64>,     // row 2, origin.z
    dims: vec4<u32>,   // voxels along i, j, k; query points
    bricks: vec4<u32>, // bricks along i, j
}

@group(0) @binding(0) var<uniform> params: Params;
// Brick words, each u64 as (low, high) u32.
@group(0) @binding(1) var<storage, read> words: array<u32>;
@group(0) @binding(2) var<storage, read> points: array<f64>;
@group(0) @binding(3) var<storage, read_write> out: array<f64>;

fn bit(i: u32, j: u32, k: u32) -> u32 {
    let w = ((k >> 2u) * params.bricks.y + (j >> 2u)) * params.bricks.x + (i >> 2u);
    let b = ((k & 3u) << 4u) | ((j & 3u) << 2u) | (i & 3u);
    return (words[2u * w + (b >> 5u)] >> (b & 31u)) & 1u;
}

fn finite(x: f64) -> bool {
    return abs(x) <= 1.0e308lf;
}

@compute @workgroup_size(64)
fn levels(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let n = gid.x + gid.y * groups.x * 64u;
    if n >= params.dims.w {
        return;
    }
    let d = vec3<f64>(points[3u * n], points[3u * n + 1u], points[3u * n + 2u])
        - vec3<f64>(params.r0.w, params.r1.w, params.r2.w);
    let g = vec3<f64>(
        params.r0.x * d.x + params.r0.y * d.y + params.r0.z * d.z,
        params.r1.x * d.x + params.r1.y * d.y + params.r1.z * d.z,
        params.r2.x * d.x + params.r2.y * d.y + params.r2.z * d.z,
    );
    if !(finite(g.x) && finite(g.y) && finite(g.z)) {
        out[n] = -0.5lf;
        return;
    }
    let base = floor(g);
    let frac = g - base;
    let dims = vec3<f64>(f64(params.dims.x), f64(params.dims.y), f64(params.dims.z));
    var corners = 0u;
    for (var c = 0u; c < 8u; c++) {
        let ijk = base + vec3<f64>(f64(c & 1u), f64((c >> 1u) & 1u), f64((c >> 2u) & 1u));
        if all(ijk >= vec3<f64>(0.0lf)) && all(ijk < dims) {
            corners |= bit(u32(ijk.x), u32(ijk.y), u32(ijk.z)) << c;
        }
    }
    var level = 0.0lf;
    if corners == 255u {
        level = 1.0lf;
    } else if corners != 0u {
        for (var c = 0u; c < 8u; c++) {
            if ((corners >> c) & 1u) == 1u {
                var w = 1.0lf;
                for (var a = 0u; a < 3u; a++) {
                    if ((c >> a) & 1u) == 1u {
                        w *= frac[a];
                    } else {
                        w *= 1.0lf - frac[a];
                    }
                }
                level += w;
            }
        }
    }
    out[n] = level - 0.5lf;
}
