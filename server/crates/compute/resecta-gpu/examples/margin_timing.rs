//! Per-call times of exact tumour distances for a surface grid: GPU (`GpuMarginField`, points
//! uploaded, distances read back) against the CPU (`MarginField::distances_grid_into` and
//! `distances_into`, rayon), at 40×40 and 200×200, on the demo-like phantom's margin field.
//! Run: `WGPU_BACKEND=vulkan cargo run --release -p resecta-gpu --example margin_timing`.
//! On lavapipe (a CPU Vulkan driver) the GPU column is a correctness run, not a performance
//! figure (2 shared cores, dev profile: 40×40 in 19 ms vs the CPU grid path's 1.4 ms, 200×200 in
//! 300 ms vs 22 ms).

use std::time::Instant;

use resecta_geom::{RoleMap, Vec3};
use resecta_gpu::{GpuContext, GpuMarginField};
use resecta_phantom::{EllipsoidSpec, GridSpec, Orientation, PhantomSpec, SphereSpec, generate};
use resecta_plan::Anatomy;

/// Median seconds per call of `f` over `reps` calls (after one warm-up).
fn median(reps: usize, f: &mut dyn FnMut()) -> f64 {
    f();
    let mut t: Vec<f64> = (0..reps)
        .map(|_| {
            let s = Instant::now();
            f();
            s.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[reps / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let ctx = GpuContext::new()?;
    println!(
        "device: {} ({:?}), f64: {}",
        ctx.info.name, ctx.info.backend, ctx.caps.f64
    );
    let spec = PhantomSpec {
        grid: GridSpec::centred(
            [120, 100, 80],
            [1.0, 0.9, 1.5],
            [0.0, 0.0, 0.0],
            Orientation::EulerDeg([4.0, -3.0, 7.0]),
        ),
        liver: vec![EllipsoidSpec {
            center: [0.0, 0.0, 0.0],
            radii: [55.0, 42.0, 38.0],
            rotation: Orientation::default(),
        }],
        tumors: vec![
            SphereSpec {
                center: [22.0, 4.0, -3.0],
                radius: 12.0,
            },
            SphereSpec {
                center: [-20.0, -8.0, 6.0],
                radius: 7.0,
            },
        ],
        vessels: vec![],
        roles: RoleMap::default(),
        max_voxels: None,
        truth_tolerance_mm: 0.05,
    };
    let p = generate(&spec)?;
    let anatomy = Anatomy::new(&p.labels, &spec.roles)?;
    let all: Vec<usize> = (0..anatomy.tumours().len()).collect();
    let target = anatomy.target(&all)?;
    let field = &target.field;
    println!("tumour triangles: {}", field.tree().triangles().len());
    let t = Instant::now();
    let mut gpu = GpuMarginField::new(&ctx, field)?;
    println!(
        "upload (once per field): {:.1} ms",
        t.elapsed().as_secs_f64() * 1e3
    );
    println!("grid      gpu ms   cpu grid ms   cpu points ms   max |gpu-cpu| mm");
    for r in [40usize, 200] {
        // A tilted plane 8 mm from the large tumour's centre, across the liver.
        let (du, dv) = (
            Vec3::new(1.0, 0.1, 0.2).normalize(),
            Vec3::new(-0.1, 1.0, 0.3).normalize(),
        );
        let origin = Vec3::new(22.0, 4.0, -3.0) + du.cross(&dv).normalize() * 8.0;
        let points: Vec<Vec3> = (0..r * r)
            .map(|k| {
                let (i, j) = (
                    (k / r) as f64 / (r - 1) as f64,
                    (k % r) as f64 / (r - 1) as f64,
                );
                origin + du * (i * 110.0 - 80.0) + dv * (j * 90.0 - 45.0)
            })
            .collect();
        let reps = if r == 40 { 50 } else { 10 };
        let mut g = vec![0.0; points.len()];
        let mut c = vec![0.0; points.len()];
        let mut err = None;
        let tg = median(reps, &mut || {
            if let Err(e) = gpu.distances_into(&points, &mut g) {
                err = Some(e);
            }
        });
        if let Some(e) = err {
            return Err(e.into());
        }
        let tc = median(reps, &mut || {
            let _ = field.distances_grid_into(r, r, &points, &mut c);
        });
        let mut c2 = vec![0.0; points.len()];
        let tp = median(reps, &mut || {
            let _ = field.distances_into(&points, &mut c2);
        });
        let diff = g
            .iter()
            .zip(&c)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        println!(
            "{r}x{r}  {:>9.3}  {:>12.3}  {:>14.3}   {diff:.2e}",
            tg * 1e3,
            tc * 1e3,
            tp * 1e3
        );
    }
    Ok(())
}
