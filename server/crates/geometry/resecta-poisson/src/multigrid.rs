//! Geometric multigrid for `lap·L x + diag(d) x = b` on vertex-centred cubic grids of `n = 2^l + 1`
//! nodes per axis, `L` the 7-point graph Laplacian with Neumann (free) boundaries.
//!
//! Every kernel is a plain loop over flat `f32` buffers, parallel over z-planes with rayon; each
//! output value is computed by one task in a fixed order, so results are bitwise independent of
//! the thread count. Norms are summed per plane in `f64` and then in plane order.

use rayon::prelude::*;

use crate::solve::PoissonParams;
use crate::system::{Solution, System};

/// One level of the hierarchy.
#[derive(Debug)]
pub(crate) struct Level {
    /// Nodes per axis.
    pub n: usize,
    /// Coefficient of the graph Laplacian (`2^(finest − level)` in finest-cell units).
    pub lap: f32,
    /// Diagonal (screening) term.
    pub diag: Vec<f32>,
    pub b: Vec<f32>,
    pub x: Vec<f32>,
    /// Residual scratch.
    pub r: Vec<f32>,
}

/// Bytes the hierarchy of a depth-`depth` grid takes (4 arrays of `f32` per node).
pub(crate) fn hierarchy_bytes(depth: u32) -> u64 {
    (0..=depth)
        .map(|l| {
            let n = (1u64 << l) + 1;
            16 * n * n * n
        })
        .sum()
}

/// The neighbour rows of row `j` of a plane and how many exist.
struct Rows<'a> {
    ym: &'a [f32],
    yp: &'a [f32],
    zm: &'a [f32],
    zp: &'a [f32],
    /// Existing neighbours outside the row (0..=4).
    count: f32,
}

/// Applies `f(i, sum_of_neighbours, neighbour_count)` for `i` in `first, first+2, …` of a row.
#[inline(always)]
fn for_row(row: &[f32], nb: &Rows<'_>, first: usize, mut f: impl FnMut(usize, f32, f32)) {
    let n = row.len();
    let mut i = first;
    if i == 0 {
        let s = if n > 1 { row[1] } else { 0.0 } + nb.ym[0] + nb.yp[0] + nb.zm[0] + nb.zp[0];
        f(0, s, nb.count + if n > 1 { 1.0 } else { 0.0 });
        i = 2;
    }
    while i + 1 < n {
        let s = row[i - 1] + row[i + 1] + nb.ym[i] + nb.yp[i] + nb.zm[i] + nb.zp[i];
        f(i, s, nb.count + 2.0);
        i += 2;
    }
    if i == n - 1 && n > 1 {
        let s = row[i - 1] + nb.ym[i] + nb.yp[i] + nb.zm[i] + nb.zp[i];
        f(i, s, nb.count + 1.0);
    }
}

/// One red–black Gauss–Seidel sweep pass over the nodes of colour `colour` (parity of i+j+k).
fn colour_pass(lv: &mut Level, zeros: &[f32], colour: usize) {
    let n = lv.n;
    let plane = n * n;
    let (lap, b, diag) = (lv.lap, &lv.b, &lv.diag);
    // Even planes, then odd: the planes a task writes are never read by another task meanwhile.
    for parity in 0..2 {
        let mut mine: Vec<(usize, &mut [f32])> = Vec::new();
        let mut others: Vec<Option<&[f32]>> = vec![None; n];
        for (k, p) in lv.x.chunks_mut(plane).enumerate() {
            if k % 2 == parity {
                mine.push((k, p));
            } else {
                others[k] = Some(p);
            }
        }
        mine.into_par_iter().for_each(|(k, xp)| {
            let zm = k.checked_sub(1).and_then(|k| others[k]);
            let zp = others.get(k + 1).copied().flatten();
            let zc = f32::from(u8::from(zm.is_some()) + u8::from(zp.is_some()));
            let (zm, zp) = (zm.unwrap_or(zeros), zp.unwrap_or(zeros));
            let bp = &b[k * plane..(k + 1) * plane];
            let dp = &diag[k * plane..(k + 1) * plane];
            for j in 0..n {
                let (before, rest) = xp.split_at_mut(j * n);
                let (row, after) = rest.split_at_mut(n);
                let ym = if j > 0 { &before[(j - 1) * n..] } else { zeros };
                let yp = if j + 1 < n { &after[..n] } else { zeros };
                let nb = Rows {
                    ym,
                    yp,
                    zm: &zm[j * n..(j + 1) * n],
                    zp: &zp[j * n..(j + 1) * n],
                    count: zc + f32::from(u8::from(j > 0) + u8::from(j + 1 < n)),
                };
                let (br, dr) = (&bp[j * n..(j + 1) * n], &dp[j * n..(j + 1) * n]);
                let first = (colour + j + k) % 2;
                // Entries of this colour depend only on entries of the other colour.
                let (ym, yp, zm, zp) = (&nb.ym[..n], &nb.yp[..n], nb.zm, nb.zp);
                let mut i = first;
                if i == 0 {
                    let s = row[1] + ym[0] + yp[0] + zm[0] + zp[0];
                    row[0] = (br[0] + lap * s) / (lap * (nb.count + 1.0) + dr[0]);
                    i = 2;
                }
                let inner = lap * (nb.count + 2.0);
                while i + 1 < n {
                    let s = row[i - 1] + row[i + 1] + ym[i] + yp[i] + zm[i] + zp[i];
                    row[i] = (br[i] + lap * s) / (inner + dr[i]);
                    i += 2;
                }
                if i == n - 1 {
                    let s = row[i - 1] + ym[i] + yp[i] + zm[i] + zp[i];
                    row[i] = (br[i] + lap * s) / (lap * (nb.count + 1.0) + dr[i]);
                }
            }
        });
    }
}

/// `sweeps` red–black Gauss–Seidel sweeps.
pub(crate) fn smooth(lv: &mut Level, zeros: &[f32], sweeps: u32) {
    for _ in 0..sweeps {
        colour_pass(lv, zeros, 0);
        colour_pass(lv, zeros, 1);
    }
}

/// `r = b − A x`; returns `(|r|², |b|²)`.
pub(crate) fn residual(lv: &mut Level, zeros: &[f32]) -> (f64, f64) {
    let n = lv.n;
    let plane = n * n;
    let (lap, x, b, diag) = (lv.lap, &lv.x, &lv.b, &lv.diag);
    let sums: Vec<(f64, f64)> =
        lv.r.par_chunks_mut(plane)
            .enumerate()
            .map(|(k, rp)| {
                let zm = if k > 0 {
                    &x[(k - 1) * plane..k * plane]
                } else {
                    zeros
                };
                let zp = if k + 1 < n {
                    &x[(k + 1) * plane..(k + 2) * plane]
                } else {
                    zeros
                };
                let zc = f32::from(u8::from(k > 0) + u8::from(k + 1 < n));
                let (mut rr, mut bb) = (0.0f64, 0.0f64);
                for j in 0..n {
                    let o = k * plane + j * n;
                    let row = &x[o..o + n];
                    let nb = Rows {
                        ym: if j > 0 { &x[o - n..o] } else { zeros },
                        yp: if j + 1 < n {
                            &x[o + n..o + 2 * n]
                        } else {
                            zeros
                        },
                        zm: &zm[j * n..(j + 1) * n],
                        zp: &zp[j * n..(j + 1) * n],
                        count: zc + f32::from(u8::from(j > 0) + u8::from(j + 1 < n)),
                    };
                    let (br, dr) = (&b[o..o + n], &diag[o..o + n]);
                    let rrow = &mut rp[j * n..(j + 1) * n];
                    for first in 0..2 {
                        for_row(row, &nb, first, |i, s, c| {
                            let v = br[i] - ((lap * c + dr[i]) * row[i] - lap * s);
                            rrow[i] = v;
                            rr += f64::from(v) * f64::from(v);
                            bb += f64::from(br[i]) * f64::from(br[i]);
                        });
                    }
                }
                (rr, bb)
            })
            .collect();
    sums.iter()
        .fold((0.0, 0.0), |(a, b), (c, d)| (a + c, b + d))
}

/// Fine nodes and weights of coarse index `c` under full weighting (`n` fine nodes per axis).
#[inline]
fn children(c: usize, n: usize) -> impl Iterator<Item = (usize, f32)> {
    [(0.5f32, -1isize), (1.0, 0), (0.5, 1)]
        .into_iter()
        .filter_map(move |(w, d)| {
            (2 * c)
                .checked_add_signed(d)
                .filter(|&f| f < n)
                .map(|f| (f, w))
        })
}

/// `coarse = Pᵀ fine` (full weighting, the transpose of trilinear interpolation), separably.
pub(crate) fn restrict(fine: &[f32], nf: usize, coarse: &mut [f32], nc: usize) {
    let pf = nf * nf;
    coarse
        .par_chunks_mut(nc * nc)
        .enumerate()
        .for_each(|(kc, cp)| {
            let mut pz = vec![0f32; pf];
            for (k, w) in children(kc, nf) {
                let src = &fine[k * pf..(k + 1) * pf];
                pz.iter_mut().zip(src).for_each(|(a, b)| *a += w * b);
            }
            let mut row = vec![0f32; nf];
            for jc in 0..nc {
                row.iter_mut().for_each(|v| *v = 0.0);
                for (j, w) in children(jc, nf) {
                    let src = &pz[j * nf..(j + 1) * nf];
                    row.iter_mut().zip(src).for_each(|(a, b)| *a += w * b);
                }
                for (ic, out) in cp[nc * jc..nc * (jc + 1)].iter_mut().enumerate() {
                    *out = children(ic, nf).map(|(i, w)| w * row[i]).sum();
                }
            }
        });
}

/// Coarse nodes and weights that interpolate fine index `f`.
#[inline]
fn parents(f: usize) -> [(usize, f32); 2] {
    if f.is_multiple_of(2) {
        [(f / 2, 1.0), (f / 2, 0.0)]
    } else {
        [(f / 2, 0.5), (f / 2 + 1, 0.5)]
    }
}

/// `fine = P coarse` (`add`: `fine += P coarse`), trilinear interpolation.
pub(crate) fn prolong(coarse: &[f32], nc: usize, fine: &mut [f32], nf: usize, add: bool) {
    fine.par_chunks_mut(nf * nf)
        .enumerate()
        .for_each(|(k, fp)| {
            let mut t = vec![0.0f32; nc];
            for j in 0..nf {
                t.iter_mut().for_each(|v| *v = 0.0);
                for (kc, wz) in parents(k) {
                    for (jc, wy) in parents(j) {
                        let w = wz * wy;
                        if w == 0.0 {
                            continue;
                        }
                        let row = &coarse[nc * (jc + nc * kc)..][..nc];
                        t.iter_mut().zip(row).for_each(|(a, c)| *a += w * c);
                    }
                }
                let out = &mut fp[j * nf..(j + 1) * nf];
                for (i, o) in out.iter_mut().enumerate() {
                    let v = if i % 2 == 0 {
                        t[i / 2]
                    } else {
                        0.5 * (t[i / 2] + t[i / 2 + 1])
                    };
                    *o = if add { *o + v } else { v };
                }
            }
        });
}

/// One V-cycle at level `l` (levels indexed coarsest first).
pub(crate) fn v_cycle(levels: &mut [Level], zeros: &[f32], l: usize, pre: u32, post: u32) {
    if l == 0 {
        smooth(&mut levels[0], zeros, COARSEST_SWEEPS);
        return;
    }
    let (lower, upper) = levels.split_at_mut(l);
    let fine = &mut upper[0];
    let coarse = &mut lower[l - 1];
    smooth(fine, zeros, pre);
    residual(fine, zeros);
    restrict(&fine.r, fine.n, &mut coarse.b, coarse.n);
    coarse.x.iter_mut().for_each(|v| *v = 0.0);
    v_cycle(lower, zeros, l - 1, pre, post);
    let (lower, upper) = levels.split_at_mut(l);
    let (fine, coarse) = (&mut upper[0], &lower[l - 1]);
    prolong(&coarse.x, coarse.n, &mut fine.x, fine.n, true);
    smooth(fine, zeros, post);
}

/// Sweeps on the coarsest (2³-node) level: enough to solve it.
pub const COARSEST_SWEEPS: u32 = 50;

/// The CPU's schedule: full multigrid from the coarsest level, then V-cycles at the finest level
/// until the relative residual is at most `tolerance` or `max_cycles` ran.
pub(crate) fn solve_cpu(system: System, params: &PoissonParams) -> Solution {
    let mut levels: Vec<Level> = system
        .levels
        .into_iter()
        .map(|s| Level {
            n: s.n,
            lap: s.lap,
            x: vec![0f32; s.b.len()],
            r: vec![0f32; s.b.len()],
            diag: s.diag,
            b: s.b,
        })
        .collect();
    let Some(top) = levels.len().checked_sub(1) else {
        return Solution::default();
    };
    let zeros = vec![0f32; levels[top].n * levels[top].n];
    let (pre, post) = (params.sweeps, params.sweeps);
    v_cycle(&mut levels, &zeros, 0, pre, post);
    for l in 1..levels.len() {
        let (lower, upper) = levels.split_at_mut(l);
        let (coarse, fine) = (&lower[l - 1], &mut upper[0]);
        prolong(&coarse.x, coarse.n, &mut fine.x, fine.n, false);
        v_cycle(&mut levels, &zeros, l, pre, post);
    }
    let mut out = Solution::default();
    loop {
        let (rr, bb) = residual(&mut levels[top], &zeros);
        let rel = if bb > 0.0 { (rr / bb).sqrt() } else { 0.0 };
        out.residuals.push(rel);
        if rel <= params.tolerance || out.cycles >= params.max_cycles {
            break;
        }
        v_cycle(&mut levels, &zeros, top, pre, post);
        out.cycles += 1;
    }
    out.x = levels.pop().map(|l| l.x).unwrap_or_default();
    out
}
