// Screened Poisson multigrid on the device: the CPU twin is resecta-poisson's `multigrid.rs`,
// whose operations these kernels transcribe (same neighbour order, same weights, f32). Every
// level's x, b, diag and r live at `off` in one array each; `Params` is one 256-byte slot per
// level and variant (colour for `smooth`, add for `prolong`).

struct Params {
    n: u32,       // nodes per axis of this level
    off: u32,     // its first node in x, b, diag, r
    nc: u32,      // nodes per axis of the next coarser level
    offc: u32,    // its first node
    lap: f32,     // Laplacian coefficient of this level
    flag: u32,    // smooth: colour (parity of i + j + k); prolong: 1 adds, 0 overwrites
    groups: u32,  // reduce: partial pairs written by `residual` at this level
    pad: u32,
}

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> x: array<f32>;
@group(0) @binding(2) var<storage, read_write> b: array<f32>;
@group(0) @binding(3) var<storage, read> diag: array<f32>;
@group(0) @binding(4) var<storage, read_write> r: array<f32>;
@group(0) @binding(5) var<storage, read_write> partials: array<f32>;
@group(0) @binding(6) var<storage, read_write> norms: array<f32>;

const GROUP: u32 = 256u;
var<workgroup> sum_rr: array<f32, 256>;
var<workgroup> sum_bb: array<f32, 256>;

fn linear_id(wid: vec3<u32>, nwg: vec3<u32>) -> u32 {
    return wid.x + wid.y * nwg.x;
}

// Sum of the existing neighbours of node (i, j, k) in the CPU's order (x−, x+, y−, y+, z−, z+)
// and their count.
fn neighbours(i: u32, j: u32, k: u32) -> vec2<f32> {
    let n = p.n;
    let o = p.off + i + n * (j + n * k);
    var s = 0.0f;
    var c = 0.0f;
    if (i > 0u) { s += x[o - 1u]; c += 1.0f; }
    if (i + 1u < n) { s += x[o + 1u]; c += 1.0f; }
    if (j > 0u) { s += x[o - n]; c += 1.0f; }
    if (j + 1u < n) { s += x[o + n]; c += 1.0f; }
    if (k > 0u) { s += x[o - n * n]; c += 1.0f; }
    if (k + 1u < n) { s += x[o + n * n]; c += 1.0f; }
    return vec2<f32>(s, c);
}

// One red–black Gauss–Seidel pass over the nodes of colour `p.flag`.
@compute @workgroup_size(256)
fn gs_smooth(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
          @builtin(local_invocation_index) lid: u32) {
    let n = p.n;
    let h = (n + 1u) / 2u;
    let t = linear_id(wid, nwg) * GROUP + lid;
    if (t >= h * n * n) { return; }
    let j = (t / h) % n;
    let k = t / (h * n);
    let i = 2u * (t % h) + ((p.flag + j + k) & 1u);
    if (i >= n) { return; }
    let o = p.off + i + n * (j + n * k);
    let sc = neighbours(i, j, k);
    x[o] = (b[o] + p.lap * sc.x) / (p.lap * sc.y + diag[o]);
}

// r = b − A x, with per-workgroup sums of r² and b² in `partials`.
@compute @workgroup_size(256)
fn residual(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) lid: u32) {
    let n = p.n;
    let g = linear_id(wid, nwg);
    let t = g * GROUP + lid;
    var rr = 0.0f;
    var bb = 0.0f;
    if (t < n * n * n) {
        let i = t % n;
        let j = (t / n) % n;
        let k = t / (n * n);
        let o = p.off + t;
        let sc = neighbours(i, j, k);
        let v = b[o] - ((p.lap * sc.y + diag[o]) * x[o] - p.lap * sc.x);
        r[o] = v;
        rr = v * v;
        bb = b[o] * b[o];
    }
    sum_rr[lid] = rr;
    sum_bb[lid] = bb;
    workgroupBarrier();
    for (var s = GROUP / 2u; s > 0u; s = s / 2u) {
        if (lid < s) {
            sum_rr[lid] += sum_rr[lid + s];
            sum_bb[lid] += sum_bb[lid + s];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        partials[2u * g] = sum_rr[0];
        partials[2u * g + 1u] = sum_bb[0];
    }
}

// norms = the sums of the `p.groups` partial pairs (one workgroup).
@compute @workgroup_size(256)
fn norm_reduce(@builtin(local_invocation_index) lid: u32) {
    var rr = 0.0f;
    var bb = 0.0f;
    for (var g = lid; g < p.groups; g += GROUP) {
        rr += partials[2u * g];
        bb += partials[2u * g + 1u];
    }
    sum_rr[lid] = rr;
    sum_bb[lid] = bb;
    workgroupBarrier();
    for (var s = GROUP / 2u; s > 0u; s = s / 2u) {
        if (lid < s) {
            sum_rr[lid] += sum_rr[lid + s];
            sum_bb[lid] += sum_bb[lid + s];
        }
        workgroupBarrier();
    }
    if (lid == 0u) {
        norms[0] = sum_rr[0];
        norms[1] = sum_bb[0];
    }
}

// Weight of fine node `2c + d − 1` under full weighting, 0 when outside `0..n`.
fn child_w(c: u32, d: u32, n: u32) -> f32 {
    let f = 2u * c + d;
    if (f < 1u || f - 1u >= n) { return 0.0f; }
    return select(0.5f, 1.0f, d == 1u);
}

// Coarse b = Pᵀ (fine r) (full weighting), summed z, then y, then x as the CPU's separable loops.
@compute @workgroup_size(256)
fn restriction(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) lid: u32) {
    let nf = p.n;
    let nc = p.nc;
    let t = linear_id(wid, nwg) * GROUP + lid;
    if (t >= nc * nc * nc) { return; }
    let ic = t % nc;
    let jc = (t / nc) % nc;
    let kc = t / (nc * nc);
    var out = 0.0f;
    for (var dx = 0u; dx < 3u; dx++) {
        let wx = child_w(ic, dx, nf);
        if (wx == 0.0f) { continue; }
        var row = 0.0f;
        for (var dy = 0u; dy < 3u; dy++) {
            let wy = child_w(jc, dy, nf);
            if (wy == 0.0f) { continue; }
            var pz = 0.0f;
            for (var dz = 0u; dz < 3u; dz++) {
                let wz = child_w(kc, dz, nf);
                if (wz == 0.0f) { continue; }
                pz += wz * r[p.off + (2u * ic + dx - 1u) + nf * ((2u * jc + dy - 1u) + nf * (2u * kc + dz - 1u))];
            }
            row += wy * pz;
        }
        out += wx * row;
    }
    b[p.offc + t] = out;
}

// Coarse x = 0 before its correction is solved.
@compute @workgroup_size(256)
fn clear(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
        @builtin(local_invocation_index) lid: u32) {
    let t = linear_id(wid, nwg) * GROUP + lid;
    if (t < p.n * p.n * p.n) { x[p.off + t] = 0.0f; }
}

// Row value t[ic] of the CPU's prolongation: Σ over the (kc, jc) parents, w ≠ 0, in order.
fn prolong_row(ic: u32, j: u32, k: u32) -> f32 {
    let nc = p.nc;
    var a = 0.0f;
    for (var pk = 0u; pk < 2u; pk++) {
        let kc = k / 2u + pk;
        let wz = select(select(0.0f, 1.0f, pk == 0u), 0.5f, (k & 1u) == 1u);
        for (var pj = 0u; pj < 2u; pj++) {
            let jc = j / 2u + pj;
            let wy = select(select(0.0f, 1.0f, pj == 0u), 0.5f, (j & 1u) == 1u);
            let w = wz * wy;
            if (w == 0.0f) { continue; }
            a += w * x[p.offc + ic + nc * (jc + nc * kc)];
        }
    }
    return a;
}

// Fine x (+)= P (coarse x), trilinear.
@compute @workgroup_size(256)
fn prolongation(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) lid: u32) {
    let nf = p.n;
    let t = linear_id(wid, nwg) * GROUP + lid;
    if (t >= nf * nf * nf) { return; }
    let i = t % nf;
    let j = (t / nf) % nf;
    let k = t / (nf * nf);
    var v = prolong_row(i / 2u, j, k);
    if ((i & 1u) == 1u) {
        v = 0.5f * (v + prolong_row(i / 2u + 1u, j, k));
    }
    let o = p.off + t;
    x[o] = select(v, x[o] + v, p.flag == 1u);
}

// Oriented points' Sobel pass (CPU twin: `resecta_poisson::sobel`): one invocation per voxel of
// a slab of `sp.z` planes of the padded mask box; `mask` holds those planes and one more on
// either side (4 voxels per word). Writes the packed gradient (x + 16, y + 16, z + 16 in 6 bits
// each, bit 18 set), 0 for background and border voxels.
struct SobelParams {
    x: u32,
    y: u32,
    z: u32,
    pad: u32,
}

@group(0) @binding(7) var<uniform> sp: SobelParams;
@group(0) @binding(8) var<storage, read> mask: array<u32>;
@group(0) @binding(9) var<storage, read_write> grad: array<u32>;

fn voxel(c: u32) -> i32 {
    return i32((mask[c / 4u] >> (8u * (c % 4u))) & 0xffu);
}

@compute @workgroup_size(256)
fn sobel(@builtin(workgroup_id) wid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
         @builtin(local_invocation_index) lid: u32) {
    let t = linear_id(wid, nwg) * GROUP + lid;
    let px = sp.x;
    let py = sp.y;
    if (t >= px * py * sp.z) { return; }
    let i = t % px;
    let j = (t / px) % py;
    let c = t + px * py;
    if (i == 0u || j == 0u || i + 1u >= px || j + 1u >= py || voxel(c) == 0) {
        grad[t] = 0u;
        return;
    }
    var g = vec3<i32>(0, 0, 0);
    var s = array<i32, 3>(1, 2, 1);
    for (var zc = 0u; zc < 3u; zc++) {
        for (var yb = 0u; yb < 3u; yb++) {
            let r = c + px * (yb + py * zc) - px - px * py;
            let l = voxel(r - 1u);
            let m = voxel(r);
            let rr = voxel(r + 1u);
            g.x += s[yb] * s[zc] * (rr - l);
            let row = l + 2 * m + rr;
            g.y += (i32(yb) - 1) * s[zc] * row;
            g.z += (i32(zc) - 1) * s[yb] * row;
        }
    }
    let u = vec3<u32>(g + vec3<i32>(16, 16, 16));
    grad[t] = u.x | (u.y << 6u) | (u.z << 12u) | (1u << 18u);
}
