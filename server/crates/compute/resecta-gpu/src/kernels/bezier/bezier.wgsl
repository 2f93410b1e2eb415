// Bézier MLE kernels (thesis Algorithms 7 and 8). Template: the f64 variant replaces the
// `alias real` line below (see mod.rs); nothing else depends on the scalar type.
alias real = f32;

// Workgroup edge (TILE×TILE threads) and control-point chunk staged in workgroup memory.
const TILE: u32 = 16u;
const CHUNK: u32 = 16u;

// 32 bytes, explicit padding (uniform structs are 16-byte aligned). Mirrors `Params` in mod.rs.
struct Params {
    m: u32,          // control points along u
    n: u32,          // control points along v
    ru: u32,         // samples along u
    rv: u32,         // samples along v
    row_start: u32,  // first output row (u index) computed by this dispatch
    row_end: u32,    // one past the last row computed
    band_start: u32, // first row held by the bound output buffer
    _pad: u32,
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

// ---- Level 1 (Algorithm 7): one thread per surface point, TILE×TILE blocks. -------------
// x → v sample b (fastest in the output), y → u sample a. Control points and the block's
// basis rows are staged chunk by chunk (CHUNK×CHUNK control points) in workgroup memory.
@group(0) @binding(1) var<storage, read> ctrl: array<real>;  // P_ij xyz at 3(i·N + j)
@group(0) @binding(2) var<storage, read> bu: array<real>;    // M×RU
@group(0) @binding(3) var<storage, read> bv: array<real>;    // N×RV
@group(0) @binding(4) var<storage, read_write> surface: array<real>; // AoS xyz, rows of RV

var<workgroup> sp: array<real, 768>;  // 3·CHUNK·CHUNK control coordinates
var<workgroup> sbu: array<real, 256>; // CHUNK functions × TILE samples (u)
var<workgroup> sbv: array<real, 256>; // CHUNK functions × TILE samples (v)

@compute @workgroup_size(16, 16)
fn surface_points(
    @builtin(local_invocation_id) lid: vec3<u32>,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let tid = lid.y * TILE + lid.x;
    let a0 = params.row_start + wid.y * TILE;
    let b0 = wid.x * TILE;
    let a = a0 + lid.y;
    let b = b0 + lid.x;
    var acc = vec3<real>(real(0.0));
    for (var i0 = 0u; i0 < params.m; i0 += CHUNK) {
        let ci = min(CHUNK, params.m - i0);
        for (var j0 = 0u; j0 < params.n; j0 += CHUNK) {
            let cj = min(CHUNK, params.n - j0);
            // Stage P[i0.., j0..] (lines 2–4), B^u and B^v of this block (lines 5–12).
            for (var k = tid; k < 3u * ci * cj; k += TILE * TILE) {
                let p = k / 3u;
                let c = k % 3u;
                let src = 3u * ((i0 + p / cj) * params.n + j0 + p % cj) + c;
                sp[k] = ctrl[src];
            }
            for (var k = tid; k < ci * TILE; k += TILE * TILE) {
                let i = k / TILE;
                let aa = a0 + k % TILE;
                var w = real(0.0);
                if aa < params.row_end { w = bu[(i0 + i) * params.ru + aa]; }
                sbu[k] = w;
            }
            for (var k = tid; k < cj * TILE; k += TILE * TILE) {
                let j = k / TILE;
                let bb = b0 + k % TILE;
                var w = real(0.0);
                if bb < params.rv { w = bv[(j0 + j) * params.rv + bb]; }
                sbv[k] = w;
            }
            workgroupBarrier(); // line 13
            // Lines 17–24: Σ_i B^u_i(a) Σ_j P_ij B^v_j(b).
            for (var i = 0u; i < ci; i++) {
                var q = vec3<real>(real(0.0));
                for (var j = 0u; j < cj; j++) {
                    let p = 3u * (i * cj + j);
                    q += vec3<real>(sp[p], sp[p + 1u], sp[p + 2u]) * sbv[j * TILE + lid.x];
                }
                acc += q * sbu[i * TILE + lid.y];
            }
            workgroupBarrier();
        }
    }
    if a < params.row_end && b < params.rv {
        let o = 3u * ((a - params.band_start) * params.rv + b);
        surface[o] = acc.x;
        surface[o + 1u] = acc.y;
        surface[o + 2u] = acc.z;
    }
}
