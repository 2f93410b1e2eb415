// Node classes of an f32 lattice for marching cubes (see mod.rs): one invocation per node row
// (j, k) of a slab of z-planes, transcribing resecta-isosurface's CPU classification: a node is
// inside when its value exceeds the iso-value and, when the border is closed, it is not on the
// lattice border; the row's state collects 1 (some inside), 2 (some outside), 4 (some value not
// finite). Classes are bytes, four to a word, each row starting on a word.

// 32 bytes. Mirrors `Params` in mod.rs.
struct Params {
    dims: vec4<u32>,  // nodes along i, j, k; first plane of the slab
    rows: u32,        // node rows in the slab
    words: u32,       // class words per row
    close: u32,       // 1: border nodes are outside
    iso: f32,
}

@group(0) @binding(0) var<uniform> params: Params;
// The slab's values, `i` fastest.
@group(0) @binding(1) var<storage, read> values: array<f32>;
@group(0) @binding(2) var<storage, read_write> classes: array<u32>;
@group(0) @binding(3) var<storage, read_write> states: array<u32>;

@compute @workgroup_size(64)
fn classify(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    let r = gid.x + gid.y * groups.x * 64u;
    if r >= params.rows {
        return;
    }
    let nx = params.dims.x;
    let j = r % params.dims.y;
    let k = params.dims.w + r / params.dims.y;
    let border_row = j == 0u || k == 0u || j + 1u == params.dims.y || k + 1u == params.dims.z;
    var state = 0u;
    var word = 0u;
    for (var i = 0u; i < nx; i++) {
        let v = values[r * nx + i];
        let border = border_row || i == 0u || i + 1u == nx;
        let inside = v > params.iso && !(params.close == 1u && border);
        word |= select(0u, 1u, inside) << (8u * (i & 3u));
        state |= select(2u, 1u, inside);
        state |= select(4u, 0u, abs(v) <= 3.4028235e38f);
        if (i & 3u) == 3u || i + 1u == nx {
            classes[r * params.words + i / 4u] = word;
            word = 0u;
        }
    }
    states[r] = state;
}
