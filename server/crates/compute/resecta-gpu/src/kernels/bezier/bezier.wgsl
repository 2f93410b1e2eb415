// Bézier MLE kernels (thesis Algorithms 7 and 8). Template: the f64 variant replaces the
// `alias real` line below (see mod.rs); nothing else depends on the scalar type.
alias real = f32;

// 32 bytes, explicit padding (uniform structs are 16-byte aligned). Mirrors `Params` in mod.rs.
struct Params {
    m: u32,          // control points along u
    n: u32,          // control points along v
    ru: u32,         // samples along u
    rv: u32,         // samples along v
    row_start: u32,  // first output row (u index) computed by this dispatch
    row_end: u32,    // one past the last row computed
    band_start: u32, // first row held by the bound output buffer
    band_rows: u32,  // rows held by the bound output buffer (one block of the normals output)
}

@group(0) @binding(0) var<uniform> params: Params;

// ---- Level 2 (Algorithm 8): one thread per basis value. --------------------------------
// binom = [C^u (m values) | C^v (n values)] from level 3 (CPU, exact u64 rounded once).
// Layout is basis-function major, bu[i·RU + a] = B_i(u_a), so a block of consecutive
// samples reads consecutive memory in level 1.
@group(0) @binding(1) var<storage, read> binom: array<real>;
@group(0) @binding(2) var<storage, read_write> bu_out: array<real>;
@group(0) @binding(3) var<storage, read_write> bv_out: array<real>;

fn bernstein(c: real, degree: u32, i: u32, a: u32, r: u32) -> real {
    let t = real(a) / real(r - 1u);
    let s = real(1.0) - t;
    var ti = real(1.0);
    for (var k = 0u; k < i; k++) { ti *= t; }
    var si = real(1.0);
    for (var k = 0u; k < degree - i; k++) { si *= s; }
    return c * ti * si;
}

@compute @workgroup_size(256)
fn basis(@builtin(global_invocation_id) gid: vec3<u32>) {
    let x = gid.x;
    if x < params.m * params.ru {
        let i = x / params.ru;
        let a = x % params.ru;
        bu_out[x] = bernstein(binom[i], params.m - 1u, i, a, params.ru);
    }
    // The dispatch covers the v table only when it is not shared (isotropy: direct addressing).
    if gid.y == 1u && x < params.n * params.rv {
        let j = x / params.rv;
        let b = x % params.rv;
        bv_out[x] = bernstein(binom[params.m + j], params.n - 1u, j, b, params.rv);
    }
}

// ---- Level 1 (Algorithm 7) as two small products, like the CPU MLE. -------------------
// Pass 1a: Q_i(b) = Σ_j P_ij B^v_j(b), thread (b, i); SoA q[(c·M + i)·RV + b].
@group(0) @binding(1) var<storage, read> ctrl: array<real>;  // P_ij xyz at 3(i·N + j)
@group(0) @binding(2) var<storage, read> bv: array<real>;    // N×RV
@group(0) @binding(3) var<storage, read_write> q_out: array<real>; // 3×M×RV

@compute @workgroup_size(64)
fn partial_sums(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let i = gid.y;
    if b >= params.rv || i >= params.m { return; }
    let x = i * params.rv + b;
    let plane = params.m * params.rv;
    var acc = vec3<real>(real(0.0));
    for (var j = 0u; j < params.n; j++) {
        let p = 3u * (i * params.n + j);
        acc += vec3<real>(ctrl[p], ctrl[p + 1u], ctrl[p + 2u]) * bv[j * params.rv + b];
    }
    q_out[x] = acc.x;
    q_out[plane + x] = acc.y;
    q_out[2u * plane + x] = acc.z;
}

// Pass 1b: S(a, b) = Σ_i B^u_i(a) Q_i(b). Thread (b, g) computes ROWS consecutive rows of
// column b, so each Q_i(b) is loaded once per ROWS outputs. No workgroup memory, no barriers.
const ROWS: u32 = 4u;
@group(0) @binding(1) var<storage, read> q: array<real>;     // 3×M×RV (pass 1a)
@group(0) @binding(2) var<storage, read> bu: array<real>;    // M×RU
@group(0) @binding(3) var<storage, read_write> surface: array<real>; // AoS xyz, rows of RV

@compute @workgroup_size(64)
fn surface_points(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let a0 = params.row_start + gid.y * ROWS;
    if b >= params.rv || a0 >= params.row_end { return; }
    let plane = params.m * params.rv;
    let last = params.row_end - 1u;
    var acc: array<vec3<real>, ROWS>;
    for (var i = 0u; i < params.m; i++) {
        let k = i * params.rv + b;
        let qi = vec3<real>(q[k], q[plane + k], q[2u * plane + k]);
        let row = i * params.ru;
        for (var r = 0u; r < ROWS; r++) {
            acc[r] += qi * bu[row + min(a0 + r, last)];
        }
    }
    for (var r = 0u; r < ROWS; r++) {
        let a = a0 + r;
        if a <= last {
            let o = 3u * ((a - params.band_start) * params.rv + b);
            surface[o] = acc[r].x;
            surface[o + 1u] = acc[r].y;
            surface[o + 2u] = acc[r].z;
        }
    }
}

// ---- Derivatives and unit normals in the same two-pass scheme. -------------------------
// ∂S/∂u(a, b) = (M−1) Σ_{i<M−1} B'^u_i(a) (Q_{i+1}(b) − Q_i(b)) reuses Q;
// ∂S/∂v(a, b) = Σ_i B^u_i(a) R_i(b) with R_i(b) = (N−1) Σ_{j<N−1} (P_i,j+1 − P_ij) B'^v_j(b).
// B'^u ((M−1)×RU) and B'^v ((N−1)×RV) are the degree-reduced bases (level 2 of `basis`).
// Pass 1a': Q and R, thread (b, i).
@group(0) @binding(4) var<storage, read> bvd: array<real>;         // (N−1)×RV
@group(0) @binding(5) var<storage, read_write> r_out: array<real>; // 3×M×RV

@compute @workgroup_size(64)
fn partial_sums_d(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let i = gid.y;
    if b >= params.rv || i >= params.m { return; }
    let x = i * params.rv + b;
    let plane = params.m * params.rv;
    var acc = vec3<real>(real(0.0));
    var accd = vec3<real>(real(0.0));
    var prev = vec3<real>(real(0.0));
    for (var j = 0u; j < params.n; j++) {
        let p = 3u * (i * params.n + j);
        let cur = vec3<real>(ctrl[p], ctrl[p + 1u], ctrl[p + 2u]);
        acc += cur * bv[j * params.rv + b];
        if j > 0u {
            accd += (cur - prev) * bvd[(j - 1u) * params.rv + b];
        }
        prev = cur;
    }
    accd *= real(params.n - 1u);
    q_out[x] = acc.x;
    q_out[plane + x] = acc.y;
    q_out[2u * plane + x] = acc.z;
    r_out[x] = accd.x;
    r_out[plane + x] = accd.y;
    r_out[2u * plane + x] = accd.z;
}

// Pass 1b': points, ∂S/∂u, ∂S/∂v and unit normals of ROWS rows of column b, written as four
// blocks of the band (each 3·band_rows·RV, AoS xyz). Degenerate samples get the zero normal,
// repaired on the host (`resecta_bezier::repair_normals`).
@group(0) @binding(4) var<storage, read> r: array<real>;    // 3×M×RV (pass 1a')
@group(0) @binding(5) var<storage, read> bud: array<real>;  // (M−1)×RU
@group(0) @binding(6) var<storage, read> tol: array<real>;  // [small, root_eps]

// `resecta_bezier::NormalTolerance::regular`: ∂u×∂v/|…|, zero when either derivative is ≈ 0
// or the two are parallel.
fn unit_normal(du: vec3<real>, dv: vec3<real>) -> vec3<real> {
    let la = length(du);
    let lb = length(dv);
    if la <= tol[0] || lb <= tol[0] { return vec3<real>(real(0.0)); }
    let c = cross(du, dv);
    let lc = length(c);
    if lc > tol[1] * la * lb { return c * (real(1.0) / lc); }
    return vec3<real>(real(0.0));
}

fn store(o: u32, v: vec3<real>) {
    surface[o] = v.x;
    surface[o + 1u] = v.y;
    surface[o + 2u] = v.z;
}

@compute @workgroup_size(64)
fn surface_normals(@builtin(global_invocation_id) gid: vec3<u32>) {
    let b = gid.x;
    let a0 = params.row_start + gid.y * ROWS;
    if b >= params.rv || a0 >= params.row_end { return; }
    let plane = params.m * params.rv;
    let last = params.row_end - 1u;
    var s: array<vec3<real>, ROWS>;
    var su: array<vec3<real>, ROWS>;
    var sv: array<vec3<real>, ROWS>;
    var qprev = vec3<real>(real(0.0));
    for (var i = 0u; i < params.m; i++) {
        let k = i * params.rv + b;
        let qi = vec3<real>(q[k], q[plane + k], q[2u * plane + k]);
        let ri = vec3<real>(r[k], r[plane + k], r[2u * plane + k]);
        let row = i * params.ru;
        for (var t = 0u; t < ROWS; t++) {
            let a = min(a0 + t, last);
            let w = bu[row + a];
            s[t] += qi * w;
            sv[t] += ri * w;
            if i > 0u {
                su[t] += (qi - qprev) * bud[row - params.ru + a];
            }
        }
        qprev = qi;
    }
    let block = 3u * params.band_rows * params.rv;
    for (var t = 0u; t < ROWS; t++) {
        let a = a0 + t;
        if a <= last {
            let o = 3u * ((a - params.band_start) * params.rv + b);
            let du = su[t] * real(params.m - 1u);
            store(o, s[t]);
            store(block + o, du);
            store(2u * block + o, sv[t]);
            store(3u * block + o, unit_normal(du, sv[t]));
        }
    }
}
