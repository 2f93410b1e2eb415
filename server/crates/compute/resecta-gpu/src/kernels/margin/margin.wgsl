// Exact point-to-tumour distances (see mod.rs): one invocation per query point walks
// resecta-margin's oriented-box tree exactly as `ObbTree::closest` does for one lane (f32 box
// bounds, f64 triangle distances, nearer child first), seeded by the hint-grid triangle of the
// point's nearest grid node. mod.rs prepends `const STACK: u32` and `const COUNT_BITS: u32`
// from resecta-margin. Requires SHADER_F64.

// 96 bytes. Mirrors `Params` in mod.rs.
struct Params {
    origin: vec4<f64>, // tree origin (xyz), reach² (w)
    grid: vec4<f64>,   // hint-grid origin (xyz), 1 / spacing (w)
    dims: vec4<u32>,   // hint nodes along x, y, z; index of the first triangle box in `boxes`
    count: u32,        // query points
    slots: u32,        // triangles
    pad0: u32,
    pad1: u32,
}

@group(0) @binding(0) var<uniform> params: Params;
// Tree nodes, then one box per triangle slot: 16 words each, `ObbNode` (centre c relative to
// the origin, axes a, half extents h, link as bits).
@group(0) @binding(1) var<storage, read> boxes: array<f32>;
// 36 per slot: `PreparedTriangle` v (0), e (9), m (18), n (27), inv_ee (30), inv_nn (33), then
// 1 where the slot is flat at corner 0 (v holds its corners; use `flat_d2`) (34), padding (35).
@group(0) @binding(2) var<storage, read> tris: array<f64>;
@group(0) @binding(3) var<storage, read> hints: array<u32>;
@group(0) @binding(4) var<storage, read> points: array<f64>;
// Squared distances; the host takes the root, as the CPU does.
@group(0) @binding(5) var<storage, read_write> out: array<f64>;

const TRI: u32 = 36u;

// `ObbNode::distance_squared`: squared distance from x (relative to the origin) to box i.
fn box_d2(i: u32, x: vec3<f32>) -> f32 {
    let b = 16u * i;
    let d = x - vec3<f32>(boxes[b], boxes[b + 1u], boxes[b + 2u]);
    var s = 0.0f;
    for (var k = 0u; k < 3u; k++) {
        let a = b + 3u + 3u * k;
        let t = max(abs(boxes[a] * d.x + boxes[a + 1u] * d.y + boxes[a + 2u] * d.z) - boxes[b + 12u + k], 0.0f);
        s += t * t;
    }
    return s;
}

fn link(i: u32) -> u32 {
    return bitcast<u32>(boxes[16u * i + 15u]);
}

fn tv(b: u32) -> vec3<f64> {
    return vec3<f64>(tris[b], tris[b + 1u], tris[b + 2u]);
}

fn dot3(a: vec3<f64>, b: vec3<f64>) -> f64 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn cross3(a: vec3<f64>, b: vec3<f64>) -> vec3<f64> {
    return vec3<f64>(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x);
}

// `PreparedTriangle::distance_squared` for one lane: the plane distance where p projects inside
// (all three in-plane edge functions ≥ 0), else the nearest of the three edge segments.
fn prepared_d2(p: vec3<f64>, b: u32) -> f64 {
    var wmin = 0.0lf;
    var seg = 0.0lf;
    var plane = 0.0lf;
    for (var k = 0u; k < 3u; k++) {
        let d = p - tv(b + 3u * k);
        let e = tv(b + 9u + 3u * k);
        let w = dot3(tv(b + 18u + 3u * k), d);
        let t = clamp(dot3(e, d) * tris[b + 30u + k], 0.0lf, 1.0lf);
        let r = d - t * e;
        let s = dot3(r, r);
        if k == 0u {
            let h = dot3(tv(b + 27u), d);
            plane = h * h * tris[b + 33u];
            wmin = w;
            seg = s;
        } else {
            wmin = select(wmin, w, w < wmin);
            seg = select(seg, s, s < seg);
        }
    }
    return select(seg, plane, wmin >= 0.0lf);
}

// `n / d` clamped to [0, 1]; 0 when d is not positive (resecta-geom's `ratio`).
fn ratio(n: f64, d: f64) -> f64 {
    if d > 0.0lf {
        return clamp(n / d, 0.0lf, 1.0lf);
    }
    return 0.0lf;
}

// Squared distance to edge k (corners k, k + 1) of the triangle with corners at b
// (resecta-geom's `on_edge`).
fn edge_d2(p: vec3<f64>, b: u32, k: u32) -> f64 {
    let a = tv(b + 3u * k);
    let e = tv(b + 3u * ((k + 1u) % 3u)) - a;
    let t = ratio(dot3(p - a, e), dot3(e, e));
    var q = a + e * t;
    if t <= 0.0lf {
        q = a;
    } else if t >= 1.0lf {
        q = tv(b + 3u * ((k + 1u) % 3u));
    }
    let r = p - q;
    return dot3(r, r);
}

// resecta-geom's `closest_point_flat` (what `closest_point_on_triangle` does for triangles flat
// at corner 0): the projection onto the plane if it falls inside, else the nearest edge point.
fn flat_d2(p: vec3<f64>, b: u32) -> f64 {
    let a = tv(b);
    let bb = tv(b + 3u);
    let c = tv(b + 6u);
    let n = cross3(bb - a, c - a);
    let len = sqrt(dot3(n, n));
    if len > 0.0lf {
        let u = n / len;
        let q = p - u * dot3(u, p - a);
        let wa = dot3(cross3(c - bb, q - bb), u);
        let wb = dot3(cross3(a - c, q - c), u);
        let wc = dot3(cross3(bb - a, q - a), u);
        let sum = wa + wb + wc;
        if wa > 0.0lf && wb > 0.0lf && wc > 0.0lf && abs(sum) <= 1.7976931348623157e308lf {
            let r = p - q;
            return dot3(r, r);
        }
    }
    return min(min(edge_d2(p, b, 0u), edge_d2(p, b, 1u)), edge_d2(p, b, 2u));
}

// Exact squared distance from p to the triangle in `slot`.
fn tri_d2(p: vec3<f64>, slot: u32) -> f64 {
    let b = TRI * slot;
    if tris[b + 34u] != 0.0lf {
        return flat_d2(p, b);
    }
    return prepared_d2(p, b);
}

// The hint slot of the grid node nearest to p (clamped to the grid); ties may round the other
// way than the CPU's, which only changes the seed, not the answer.
fn hint(p: vec3<f64>) -> u32 {
    let t = floor((p - params.grid.xyz) * params.grid.w + vec3<f64>(0.5lf));
    let hi = vec3<f64>(vec3<u32>(params.dims.xyz) - vec3<u32>(1u));
    let ijk = vec3<u32>(clamp(t, vec3<f64>(0.0lf), hi));
    return hints[(ijk.z * params.dims.y + ijk.y) * params.dims.x + ijk.x];
}

@compute @workgroup_size(64)
fn distances(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let i = gid.x + gid.y * groups.x * 64u;
    if i >= params.count {
        return;
    }
    let p = vec3<f64>(points[3u * i], points[3u * i + 1u], points[3u * i + 2u]);
    let rel = p - params.origin.xyz;
    if dot3(rel, rel) > params.origin.w {
        // Beyond the reach of the f32 bounds (the CPU uses a plain BVH there): every triangle.
        var far = tri_d2(p, 0u);
        for (var s = 1u; s < params.slots; s++) {
            far = min(far, tri_d2(p, s));
        }
        out[i] = far;
        return;
    }
    let x = vec3<f32>(rel);
    var best = tri_d2(p, hint(p));
    var bound = f32(best);
    var stack_node: array<u32, STACK>;
    var stack_d2: array<f32, STACK>;
    stack_node[0] = 0u;
    stack_d2[0] = box_d2(0u, x);
    var len = 1u;
    while len > 0u {
        len -= 1u;
        if !(stack_d2[len] < bound) {
            continue;
        }
        let l = link(stack_node[len]);
        let first = l >> COUNT_BITS;
        let count = l & ((1u << COUNT_BITS) - 1u);
        if count > 0u {
            for (var j = 0u; j < count; j++) {
                if box_d2(params.dims.w + first + j, x) < bound {
                    let d = tri_d2(p, first + j);
                    if d < best {
                        best = d;
                        bound = f32(best);
                    }
                }
            }
            continue;
        }
        let dl = box_d2(first, x);
        let dr = box_d2(first + 1u, x);
        var near = first;
        var far = first + 1u;
        var dn = dl;
        var df = dr;
        if !(dl <= dr) {
            near = first + 1u;
            far = first;
            dn = dr;
            df = dl;
        }
        if df < bound {
            stack_node[len] = far;
            stack_d2[len] = df;
            len += 1u;
        }
        if dn < bound {
            stack_node[len] = near;
            stack_d2[len] = dn;
            len += 1u;
        }
    }
    out[i] = best;
}
