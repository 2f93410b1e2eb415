// The band and side components of a volumetry cut (see mod.rs); the CPU twin is
// `resecta_volumetry::Volumetry`'s splat and union–find. Requires SHADER_F64.
//
// Keys: `dkey[v]` holds !bits(f32(d²)) of the voxel's nearest sample (0: not in the band) and
// `kkey[v]` !index of the smallest such sample, both by atomicMax, so that the result does not
// depend on the order of the invocations.

// 192 bytes. Mirrors `Params` in mod.rs.
struct Params {
    origin: vec4<f64>, // grid origin (xyz), hs (w)
    col0: vec4<f64>,   // grid linear map columns (xyz); rho (col0.w)
    col1: vec4<f64>,
    col2: vec4<f64>,
    lo: vec4<u32>,     // bounding box's first voxel (xyz), samples (w)
    dims: vec4<u32>,   // bounding-box dims (xyz), liver voxels (w)
    caps: vec4<u32>,   // band capacity, roots capacity, resected roots, unused
    pad: vec4<u32>,
}

@group(0) @binding(0) var<uniform> params: Params;
// The liver bit-packed over bounding-box cells: per 32 cells, their liver bits and the compact
// index of the first liver cell among them (see `compact`).
@group(0) @binding(1) var<storage, read> cell_words: array<vec2<u32>>;
// STRIDE per sample: point (0), normal (3), g (6), n_idx (9), axis (12), outer ranges (13..17).
@group(0) @binding(2) var<storage, read> samples: array<f64>;
@group(0) @binding(3) var<storage, read_write> dkey: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> kkey: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> parent: array<atomic<u32>>;
// Band voxels, component roots.
@group(0) @binding(6) var<storage, read_write> counts: array<atomic<u32>>;
// 8 per band voxel: cell (by `band_arg`), then by `collect` its nearest sample and the roots of
// its face neighbours −x, +x, −y, +y, −z, +z.
@group(0) @binding(7) var<storage, read_write> band_out: array<u32>;
@group(0) @binding(8) var<storage, read_write> roots_out: array<u32>;
// Roots of the resected components, sorted.
@group(0) @binding(9) var<storage, read> resected: array<u32>;
@group(0) @binding(10) var<storage, read_write> mask: array<atomic<u32>>;
// `dkey` and `parent` as plain reads, for the passes that only read them (no atomics needed).
@group(0) @binding(11) var<storage, read> dkey_r: array<u32>;
@group(0) @binding(12) var<storage, read> parent_r: array<u32>;

const NONE: u32 = 0xffffffffu;
const STRIDE: u32 = 18u;
const GROUP: u32 = 64u;

fn invocation(gid: vec3<u32>, groups: vec3<u32>) -> u32 {
    return gid.x + gid.y * groups.x * GROUP;
}

// Compact index of bounding-box cell `cell`, NONE outside the liver.
fn compact(cell: u32) -> u32 {
    let w = cell_words[cell / 32u];
    let bit = cell % 32u;
    if ((w.x >> bit) & 1u) == 0u {
        return NONE;
    }
    return w.y + countOneBits(w.x & ((1u << bit) - 1u));
}

fn cells() -> u32 {
    return params.dims.x * params.dims.y * params.dims.z;
}

fn vec_at(b: u32) -> vec3<f64> {
    return vec3<f64>(samples[b], samples[b + 1u], samples[b + 2u]);
}

// `Vec3::dot`: (a.x b.x + a.y b.y) + a.z b.z.
fn dot3(a: vec3<f64>, b: vec3<f64>) -> f64 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

// `Grid::voxel_center` of bounding-box voxel ijk: origin + ((c0 i + c1 j) + c2 k).
fn centre(ijk: vec3<u32>) -> vec3<f64> {
    let i = vec3<f64>(ijk + params.lo.xyz);
    return params.origin.xyz + ((params.col0.xyz * i.x + params.col1.xyz * i.y) + params.col2.xyz * i.z);
}

// Bits of x (finite, ≥ 0) rounded to the nearest f32, ties to even, as Rust's `as f32` (WGSL's
// conversion may round either way).
fn f32_bits(x: f64) -> u32 {
    let r = f32(x);
    let rb = bitcast<u32>(r);
    var lo = rb;
    var hi = rb;
    if f64(r) > x {
        lo = rb - 1u;
    } else if f64(r) < x {
        hi = rb + 1u;
    } else {
        return rb;
    }
    let mid = (f64(bitcast<f32>(lo)) + f64(bitcast<f32>(hi))) * 0.5lf;
    if x < mid {
        return lo;
    }
    if x > mid {
        return hi;
    }
    return select(hi, lo, (lo & 1u) == 0u);
}

// The voxels of sample k's slab-disc (`SlabDisc::column`, `SlabDisc::reach`): the minimum key
// first (arg = false), then the smallest sample index at that key (arg = true).
fn visit(k: u32, arg: bool) {
    let b = STRIDE * k;
    let m = u32(samples[b + 12u]);
    let o1 = (m + 1u) % 3u;
    let o2 = (m + 2u) % 3u;
    let a0 = i32(samples[b + 13u]);
    let a1 = i32(samples[b + 14u]);
    let b0 = i32(samples[b + 15u]);
    let b1 = i32(samples[b + 16u]);
    let p = vec_at(b);
    let n = vec_at(b + 3u);
    var g = vec_at(b + 6u);
    var ni = vec_at(b + 9u);
    let hs = params.origin.w;
    let rho = params.col0.w;
    var dims = params.dims.xyz;
    let len = f64(dims[m]);
    for (var a = a0; a <= a1; a++) {
        for (var bb = b0; bb <= b1; bb++) {
            let rest = ni[o1] * (f64(a) - g[o1]) + ni[o2] * (f64(bb) - g[o2]);
            let t0 = (-hs - rest) / ni[m];
            let t1 = (hs - rest) / ni[m];
            let lo = max(ceil(min(t0, t1) + g[m]), 0.0lf);
            let hi = min(floor(max(t0, t1) + g[m]), len - 1.0lf);
            if lo > hi {
                continue;
            }
            for (var c = u32(lo); c <= u32(hi); c++) {
                var ijk = vec3<u32>(0u);
                ijk[m] = c;
                ijk[o1] = u32(a);
                ijk[o2] = u32(bb);
                let v = compact(ijk.x + dims.x * (ijk.y + dims.y * ijk.z));
                if v == NONE {
                    continue;
                }
                let d = centre(ijk) - p;
                let off = dot3(n, d);
                let d2 = dot3(d, d);
                if d2 - off * off > rho * rho {
                    continue;
                }
                let key = ~f32_bits(d2);
                if !arg {
                    atomicMax(&dkey[v], key);
                } else if atomicLoad(&dkey[v]) == key && atomicMax(&kkey[v], ~k) == 0u {
                    // The voxel's first write: list it once.
                    let s = atomicAdd(&counts[0], 1u);
                    if s < params.caps.x {
                        band_out[8u * s] = ijk.x + dims.x * (ijk.y + dims.y * ijk.z);
                    }
                }
            }
        }
    }
}

@compute @workgroup_size(64)
fn band_min(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = invocation(gid, groups);
    if k < params.lo.w {
        visit(k, false);
    }
}

@compute @workgroup_size(64)
fn band_arg(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let k = invocation(gid, groups);
    if k < params.lo.w {
        visit(k, true);
    }
}

// Union–find with atomicMin on parents: every root is its component's smallest compact index.
fn find(x0: u32) -> u32 {
    var x = x0;
    var p = atomicLoad(&parent[x]);
    while p != x {
        // Path halving: the grandparent is in the same set, and smaller.
        let gp = atomicLoad(&parent[p]);
        if gp != p {
            atomicMin(&parent[x], gp);
        }
        x = gp;
        p = atomicLoad(&parent[x]);
    }
    return x;
}

fn unite(a0: u32, b0: u32) {
    var a = a0;
    var b = b0;
    loop {
        a = find(a);
        b = find(b);
        if a == b {
            return;
        }
        if a > b {
            let t = a;
            a = b;
            b = t;
        }
        let old = atomicMin(&parent[b], a);
        if old == b {
            return;
        }
        b = old;
    }
}

fn free(v: u32) -> bool {
    return v != NONE && dkey_r[v] == 0u;
}

// One invocation per bounding-box row: a free voxel's parent is the first voxel of its run of
// free voxels (the run's smallest compact index); other liver voxels are their own.
@compute @workgroup_size(64)
fn cc_init(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let row = invocation(gid, groups);
    if row >= params.dims.y * params.dims.z {
        return;
    }
    let base = row * params.dims.x;
    var start = NONE;
    for (var x = 0u; x < params.dims.x; x++) {
        let v = compact(base + x);
        if !free(v) {
            start = NONE;
            if v != NONE {
                atomicStore(&parent[v], v);
            }
            continue;
        }
        if start == NONE {
            start = v;
        }
        atomicStore(&parent[v], start);
    }
}

// Whether the free voxel at `cell` begins its run.
fn starts(cell: u32) -> bool {
    return cell % params.dims.x == 0u || !free(compact(cell - 1u));
}

// Runs are joined at the first voxel of their overlap with a run of the row below (−y) or the
// slice below (−z), where one of the two runs starts: one union per overlap.
@compute @workgroup_size(64)
fn cc_union(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let cell = invocation(gid, groups);
    if cell >= cells() {
        return;
    }
    let v = compact(cell);
    if !free(v) {
        return;
    }
    let dx = params.dims.x;
    let dxy = dx * params.dims.y;
    let s = starts(cell);
    if (cell / dx) % params.dims.y > 0u {
        let u = compact(cell - dx);
        if free(u) && (s || starts(cell - dx)) {
            unite(v, u);
        }
    }
    if cell >= dxy {
        let u = compact(cell - dxy);
        if free(u) && (s || starts(cell - dxy)) {
            unite(v, u);
        }
    }
}

@compute @workgroup_size(64)
fn cc_flatten(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let v = invocation(gid, groups);
    if v >= params.dims.w {
        return;
    }
    let r = find(v);
    atomicStore(&parent[v], r);
    if r == v && dkey_r[v] == 0u {
        let s = atomicAdd(&counts[1], 1u);
        if s < params.caps.y {
            roots_out[s] = v;
        }
    }
}

// The root of the neighbour `cell + step` (`ok`: inside the box), NONE if band or not liver.
fn neighbour_root(cell: u32, step: i32, ok: bool) -> u32 {
    if !ok {
        return NONE;
    }
    let u = compact(u32(i32(cell) + step));
    if !free(u) {
        return NONE;
    }
    return parent_r[u];
}

@compute @workgroup_size(64)
fn collect(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    // One invocation per band voxel listed by `band_arg`.
    let s = invocation(gid, groups);
    if s >= min(atomicLoad(&counts[0]), params.caps.x) {
        return;
    }
    let cell = band_out[8u * s];
    let v = compact(cell);
    let d = params.dims.xyz;
    let x = cell % d.x;
    let y = (cell / d.x) % d.y;
    let z = cell / (d.x * d.y);
    let sx = 1i;
    let sy = i32(d.x);
    let sz = i32(d.x * d.y);
    let o = 8u * s;
    band_out[o + 1u] = ~atomicLoad(&kkey[v]);
    band_out[o + 2u] = neighbour_root(cell, -sx, x > 0u);
    band_out[o + 3u] = neighbour_root(cell, sx, x + 1u < d.x);
    band_out[o + 4u] = neighbour_root(cell, -sy, y > 0u);
    band_out[o + 5u] = neighbour_root(cell, sy, y + 1u < d.y);
    band_out[o + 6u] = neighbour_root(cell, -sz, z > 0u);
    band_out[o + 7u] = neighbour_root(cell, sz, z + 1u < d.z);
}

@compute @workgroup_size(64)
fn mark(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) groups: vec3<u32>) {
    let v = invocation(gid, groups);
    if v >= params.dims.w || dkey_r[v] != 0u {
        return;
    }
    let r = parent_r[v];
    // Binary search of the sorted resected roots.
    var lo = 0u;
    var hi = params.caps.z;
    while lo < hi {
        let mid = (lo + hi) / 2u;
        if resected[mid] < r {
            lo = mid + 1u;
        } else {
            hi = mid;
        }
    }
    if lo < params.caps.z && resected[lo] == r {
        atomicOr(&mask[v / 32u], 1u << (v % 32u));
    }
}
