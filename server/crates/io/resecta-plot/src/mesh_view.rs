//! Pictures of triangle meshes (reconstructions in study reports): flat-shaded orthographic views
//! as SVG text and PNG bytes, one mesh or several side by side.
//!
//! The mesh is projected along [`MeshView::view_dir`] with [`MeshView::up`] pointing up and
//! `view_dir × up` to the right, scaled to fit the picture with a margin of 5 % of its smaller
//! side, and drawn with the painter's algorithm: triangles sorted from the farthest mean depth to
//! the nearest, each one flat polygon shaded by a head-light, `0.25 + 0.75 |n · view_dir|` of
//! the colour, so back-faces (seen through a hole, from inside) are drawn like front faces. Each
//! polygon has a hairline stroke of its own colour, which hides the seams that anti-aliasing
//! leaves between neighbours. Triangles whose projection has no area (edge-on, or degenerate)
//! are not drawn. Overlay points (samples, say) are dots drawn over the mesh, whatever their
//! depth. The PNG is the SVG rasterised by resvg, as for figures.
//!
//! Plain data in, so that this crate needs nothing above the io layer: vertices as `[f64; 3]`,
//! triangles as vertex indices.

use std::fmt::Write as _;

use crate::figure::{Colour, MAX_SIZE, MIN_SIZE, PlotError};

/// How meshes are pictured: the size of one picture (one panel of [`mesh_panel_svg`]), the
/// direction of view and the colours.
#[derive(Debug, Clone, PartialEq)]
pub struct MeshView {
    /// Width of one picture in pixels (SVG user units), within `MIN_SIZE..=MAX_SIZE` (100 to
    /// 4096).
    pub width: u32,
    /// Height of one picture in pixels, within `MIN_SIZE..=MAX_SIZE`.
    pub height: u32,
    /// The direction the viewer looks in (from the eye into the scene); any non-zero length.
    pub view_dir: [f64; 3],
    /// Up in the picture: its part across `view_dir` points up; it must not be parallel to
    /// `view_dir`.
    pub up: [f64; 3],
    /// The mesh's colour, lit head-on.
    pub colour: Colour,
    /// A caption above the picture (above all panels, for [`mesh_panel_svg`]).
    pub title: Option<String>,
    /// The colour of the overlay points.
    pub point_colour: Colour,
    /// The radius of the overlay points' dots in pixels (finite, not negative; 0 draws none).
    pub point_radius: f64,
}

impl MeshView {
    /// A `width × height` anterior view of RAS coordinates (looking along −y, superior up, the
    /// patient's right on the left), a flesh-coloured mesh and blue dots of radius 2.5 pixels.
    pub fn anterior(width: u32, height: u32) -> Self {
        Self {
            width,
            height,
            view_dir: [0.0, -1.0, 0.0],
            up: [0.0, 0.0, 1.0],
            colour: Colour::rgb(205, 120, 100),
            title: None,
            point_colour: Colour::BLUE,
            point_radius: 2.5,
        }
    }
}

/// One mesh of a panel picture ([`mesh_panel_svg`]), with its overlay points and title.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeshPanel<'a> {
    pub vertices: &'a [[f64; 3]],
    pub triangles: &'a [[u32; 3]],
    /// Overlay points, drawn as dots.
    pub points: &'a [[f64; 3]],
    /// Written above this panel's mesh.
    pub title: Option<&'a str>,
}

/// The mesh as an SVG picture (`view.width × view.height`); `view.title` is written above it.
pub fn mesh_svg(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    points: &[[f64; 3]],
    view: &MeshView,
) -> Result<String, PlotError> {
    let panel = MeshPanel {
        vertices,
        triangles,
        points,
        title: view.title.as_deref(),
    };
    render(&[panel], view, 1, None).map(|(svg, _, _)| svg)
}

/// The picture of [`mesh_svg`] as a PNG image (8-bit RGBA, `view.width × view.height`).
pub fn mesh_png(
    vertices: &[[f64; 3]],
    triangles: &[[u32; 3]],
    points: &[[f64; 3]],
    view: &MeshView,
) -> Result<Vec<u8>, PlotError> {
    let svg = mesh_svg(vertices, triangles, points, view)?;
    crate::render::svg_to_png(&svg, view.width, view.height)
}

/// Several meshes side by side, `columns` per row (fewer when there are fewer panels), each in
/// a `view.width × view.height` cell seen the same way and at the same scale (the largest at
/// which every mesh fits its cell), so that sizes compare; `view.title` is a caption above all
/// of them, each panel's title is written above its mesh. The whole picture must be at most
/// `MAX_SIZE` (4096) pixels wide and high.
pub fn mesh_panel_svg(
    panels: &[MeshPanel<'_>],
    view: &MeshView,
    columns: u32,
) -> Result<String, PlotError> {
    render(panels, view, columns, view.title.as_deref()).map(|(svg, _, _)| svg)
}

/// The picture of [`mesh_panel_svg`] as a PNG image (8-bit RGBA).
pub fn mesh_panel_png(
    panels: &[MeshPanel<'_>],
    view: &MeshView,
    columns: u32,
) -> Result<Vec<u8>, PlotError> {
    let (svg, width, height) = render(panels, view, columns, view.title.as_deref())?;
    crate::render::svg_to_png(&svg, width, height)
}

// ---------------------------------------------------------------------------------------------

type V3 = [f64; 3];

/// Width in pixels of the stroke around each triangle, in its fill colour (hides seams).
const HAIRLINE: f64 = 0.6;

fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn unit(a: V3) -> Option<V3> {
    let n = dot(a, a).sqrt();
    (n.is_finite() && n > 0.0).then(|| a.map(|c| c / n))
}

/// The picture's axes: right, up and into the scene, orthonormal.
struct Camera {
    right: V3,
    up: V3,
    dir: V3,
}

impl Camera {
    fn new(view: &MeshView) -> Result<Self, PlotError> {
        let finite = |v: &V3| v.iter().all(|c| c.is_finite());
        if !finite(&view.view_dir) || !finite(&view.up) {
            return Err(PlotError::BadView("view_dir and up must be finite"));
        }
        let dir = unit(view.view_dir).ok_or(PlotError::BadView("view_dir is zero"))?;
        let up = unit(view.up).ok_or(PlotError::BadView("up is zero"))?;
        let right = unit(cross(dir, up))
            .filter(|r| dot(cross(dir, up), *r) > 1e-9)
            .ok_or(PlotError::BadView("up is parallel to view_dir"))?;
        Ok(Self {
            right,
            up: cross(right, dir),
            dir,
        })
    }

    /// (right, up, depth) of a point.
    fn project(&self, p: V3) -> V3 {
        [dot(p, self.right), dot(p, self.up), dot(p, self.dir)]
    }
}

/// A panel checked and projected.
struct Projected<'a> {
    panel: &'a MeshPanel<'a>,
    vertices: Vec<V3>,
    points: Vec<V3>,
    /// Bounds of the projected vertices and points: (min right, max right, min up, max up).
    bounds: Option<[f64; 4]>,
}

fn project<'a>(
    index: usize,
    panel: &'a MeshPanel<'a>,
    camera: &Camera,
) -> Result<Projected<'a>, PlotError> {
    let finite = |v: &V3| v.iter().all(|c| c.is_finite());
    if let Some(i) = panel.vertices.iter().position(|v| !finite(v)) {
        return Err(PlotError::NonFiniteCoordinate {
            mesh: index,
            what: "vertex",
            index: i,
        });
    }
    if let Some(i) = panel.points.iter().position(|v| !finite(v)) {
        return Err(PlotError::NonFiniteCoordinate {
            mesh: index,
            what: "point",
            index: i,
        });
    }
    let n = panel.vertices.len();
    for (t, tri) in panel.triangles.iter().enumerate() {
        if let Some(&bad) = tri.iter().find(|&&i| i as usize >= n) {
            return Err(PlotError::VertexIndex {
                mesh: index,
                triangle: t,
                index: bad,
                vertices: n,
            });
        }
    }
    let vertices: Vec<V3> = panel.vertices.iter().map(|&v| camera.project(v)).collect();
    let points: Vec<V3> = panel.points.iter().map(|&v| camera.project(v)).collect();
    let drawn = (!panel.triangles.is_empty())
        .then_some(&vertices)
        .into_iter()
        .flatten()
        .chain(&points);
    let bounds = drawn.fold(None, |b: Option<[f64; 4]>, p| {
        let [a, c, d, e] = b.unwrap_or([p[0], p[0], p[1], p[1]]);
        Some([a.min(p[0]), c.max(p[0]), d.min(p[1]), e.max(p[1])])
    });
    Ok(Projected {
        panel,
        vertices,
        points,
        bounds,
    })
}

/// Font size of titles in a picture `height` pixels high.
fn title_size(height: u32) -> f64 {
    (f64::from(height) * 0.045).clamp(11.0, 28.0)
}

/// Escapes text for SVG content.
fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            c if c.is_control() => out.push(' '),
            c => out.push(c),
        }
    }
    out
}

fn hex(c: Colour) -> String {
    format!("#{:02x}{:02x}{:02x}", c.r, c.g, c.b)
}

fn text(out: &mut String, x: f64, baseline: f64, size: f64, bold: bool, content: &str) {
    let weight = if bold { " font-weight=\"bold\"" } else { "" };
    let _ = writeln!(
        out,
        "<text x=\"{x:.1}\" y=\"{baseline:.1}\" font-family=\"sans-serif\" font-size=\"{size:.1}\"\
         {weight} text-anchor=\"middle\" fill=\"#000000\">{}</text>",
        escape(content)
    );
}

/// The SVG of `panels` and its size in pixels.
fn render(
    panels: &[MeshPanel<'_>],
    view: &MeshView,
    columns: u32,
    caption: Option<&str>,
) -> Result<(String, u32, u32), PlotError> {
    let (cw, ch) = (view.width, view.height);
    let ok = |s: u32| (MIN_SIZE..=MAX_SIZE).contains(&s);
    if !ok(cw) || !ok(ch) {
        return Err(PlotError::BadSize {
            width: cw,
            height: ch,
        });
    }
    if columns == 0 {
        return Err(PlotError::BadView("columns must be at least 1"));
    }
    if !view.point_radius.is_finite() || view.point_radius < 0.0 {
        return Err(PlotError::BadView(
            "point_radius must be finite and not negative",
        ));
    }
    let camera = Camera::new(view)?;
    let projected = panels
        .iter()
        .enumerate()
        .map(|(i, p)| project(i, p, &camera))
        .collect::<Result<Vec<_>, _>>()?;
    if projected.iter().all(|p| p.bounds.is_none()) {
        return Err(PlotError::NoData);
    }

    let count = u32::try_from(panels.len()).unwrap_or(u32::MAX);
    let cols = columns.min(count);
    let rows = count.div_ceil(cols);
    let caption_band = caption.map_or(0.0, |_| (title_size(ch) * 1.8).round());
    let total = |cells: u32, side: u32, band: f64| u64::from(cells) * u64::from(side) + band as u64;
    let (tw, th) = (total(cols, cw, 0.0), total(rows, ch, caption_band));
    if tw > u64::from(MAX_SIZE) || th > u64::from(MAX_SIZE) {
        return Err(PlotError::BadSize {
            width: u32::try_from(tw).unwrap_or(u32::MAX),
            height: u32::try_from(th).unwrap_or(u32::MAX),
        });
    }
    let (tw, th) = (tw as u32, th as u32);

    // One scale for all panels: the largest at which each fits its cell.
    let margin = 0.05 * f64::from(cw.min(ch)) + view.point_radius;
    let title_band = (title_size(ch) * 1.6).round();
    let scale = projected
        .iter()
        .filter_map(|p| {
            let [x0, x1, y0, y1] = p.bounds?;
            let band = if p.panel.title.is_some() {
                title_band
            } else {
                0.0
            };
            let w = (f64::from(cw) - 2.0 * margin).max(1.0);
            let h = (f64::from(ch) - 2.0 * margin - band).max(1.0);
            Some(fit(w, x1 - x0).min(fit(h, y1 - y0)))
        })
        .fold(f64::INFINITY, f64::min);
    let scale = if scale.is_finite() { scale } else { 1.0 };

    let mut out = String::with_capacity(
        512 + panels
            .iter()
            .map(|p| 72 * p.triangles.len() + 48 * p.points.len())
            .sum::<usize>(),
    );
    let _ = writeln!(
        out,
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{tw}\" height=\"{th}\" \
         viewBox=\"0 0 {tw} {th}\">\n<rect x=\"0\" y=\"0\" width=\"{tw}\" height=\"{th}\" \
         fill=\"#ffffff\"/>"
    );
    if let Some(c) = caption {
        let size = title_size(ch);
        text(
            &mut out,
            f64::from(tw) / 2.0,
            caption_band * 0.68,
            size * 1.1,
            true,
            c,
        );
    }
    for (k, p) in projected.iter().enumerate() {
        let k = k as u32;
        let ox = f64::from((k % cols) * cw);
        let oy = caption_band + f64::from((k / cols) * ch);
        let band = if p.panel.title.is_some() {
            title_band
        } else {
            0.0
        };
        if let Some(t) = p.panel.title {
            let size = title_size(ch);
            text(
                &mut out,
                ox + f64::from(cw) / 2.0,
                oy + margin * 0.5 + size,
                size,
                false,
                t,
            );
        }
        let Some([x0, x1, y0, y1]) = p.bounds else {
            continue;
        };
        // The centre of the drawn box maps to the centre of the cell's free area.
        let (cx, cy) = ((x0 + x1) / 2.0, (y0 + y1) / 2.0);
        let px = ox + f64::from(cw) / 2.0;
        let py = oy + band + (f64::from(ch) - band) / 2.0;
        let to_pixel = |v: &V3| [px + (v[0] - cx) * scale, py - (v[1] - cy) * scale];
        draw_triangles(&mut out, p, view, &camera, &to_pixel);
        if view.point_radius > 0.0 && !p.points.is_empty() {
            let _ = writeln!(out, "<g fill=\"{}\">", hex(view.point_colour));
            for v in &p.points {
                let [x, y] = to_pixel(v);
                let _ = writeln!(
                    out,
                    "<circle cx=\"{x:.1}\" cy=\"{y:.1}\" r=\"{:.1}\"/>",
                    view.point_radius
                );
            }
            out.push_str("</g>\n");
        }
    }
    out.push_str("</svg>\n");
    Ok((out, tw, th))
}

/// The scale that fits `span` into `room` pixels (infinite for a flat span).
fn fit(room: f64, span: f64) -> f64 {
    if span > 0.0 {
        room / span
    } else {
        f64::INFINITY
    }
}

fn draw_triangles(
    out: &mut String,
    p: &Projected<'_>,
    view: &MeshView,
    camera: &Camera,
    to_pixel: &impl Fn(&V3) -> [f64; 2],
) {
    let v = &p.vertices;
    let world = p.panel.vertices;
    // (mean depth, triangle, shade), drawn from the farthest.
    let mut order: Vec<(f64, usize, f64)> = Vec::with_capacity(p.panel.triangles.len());
    for (t, tri) in p.panel.triangles.iter().enumerate() {
        let [a, b, c] = tri.map(|i| i as usize);
        let [pa, pb, pc] = [&v[a], &v[b], &v[c]].map(to_pixel);
        let area2 = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0]);
        if area2.abs() < 1e-9 || !area2.is_finite() {
            continue;
        }
        let normal = cross(sub(world[b], world[a]), sub(world[c], world[a]));
        let Some(n) = unit(normal) else { continue };
        let shade = 0.25 + 0.75 * dot(n, camera.dir).abs();
        order.push(((v[a][2] + v[b][2] + v[c][2]) / 3.0, t, shade));
    }
    order.sort_unstable_by(|x, y| y.0.total_cmp(&x.0).then(x.1.cmp(&y.1)));
    let _ = writeln!(
        out,
        "<g stroke-width=\"{HAIRLINE}\" stroke-linejoin=\"round\">"
    );
    let c = view.colour;
    for (_, t, shade) in order {
        let lit = |x: u8| (f64::from(x) * shade).round().clamp(0.0, 255.0) as u8;
        let colour = hex(Colour::rgb(lit(c.r), lit(c.g), lit(c.b)));
        out.push_str("<polygon points=\"");
        for (k, &i) in p.panel.triangles[t].iter().enumerate() {
            let [x, y] = to_pixel(&v[i as usize]);
            let sep = if k == 0 { "" } else { " " };
            let _ = write!(out, "{sep}{x:.1},{y:.1}");
        }
        let _ = writeln!(out, "\" fill=\"{colour}\" stroke=\"{colour}\"/>");
    }
    out.push_str("</g>\n");
}
