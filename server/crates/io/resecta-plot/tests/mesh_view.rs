//! Mesh pictures: SVG structure, PNG size and content, shading and depth order, panels at one
//! scale, and bad input as `PlotError`s.
#![allow(clippy::unwrap_used, clippy::panic)] // test helpers

use quick_xml::Reader;
use quick_xml::events::Event;
use resecta_plot::{
    Colour, MeshPanel, MeshView, PlotError, mesh_panel_png, mesh_panel_svg, mesh_png, mesh_svg,
};

const TET_V: [[f64; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [40.0, 0.0, 0.0],
    [0.0, 30.0, 0.0],
    [0.0, 0.0, 20.0],
];
const TET_T: [[u32; 3]; 4] = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];

/// A view from a general direction, where no face of the tetrahedron is edge-on.
fn view() -> MeshView {
    MeshView {
        view_dir: [-1.0, -0.7, -0.4],
        ..MeshView::anterior(320, 240)
    }
}

/// An element's name and attributes.
type Element = (String, Vec<(String, String)>);

/// Elements by name (`polygon`, `circle`, `text`, …) and the text content; panics if the SVG is
/// not well-formed XML.
// quick_xml's other events (comments, declarations, ...) are not counted.
#[allow(clippy::wildcard_enum_match_arm)]
fn elements(svg: &str) -> (Vec<Element>, String) {
    let mut reader = Reader::from_str(svg);
    let (mut out, mut text) = (Vec::new(), String::new());
    loop {
        match reader.read_event().unwrap() {
            Event::Eof => return (out, text),
            Event::Start(e) | Event::Empty(e) => {
                let attrs = e
                    .attributes()
                    .map(|a| {
                        let a = a.unwrap();
                        let key = a.key.as_ref().to_owned();
                        let value = a.normalized_value(quick_xml::XmlVersion::Implicit1_0);
                        (key, value.unwrap().into_owned())
                    })
                    .collect();
                out.push((e.name().as_ref().to_owned(), attrs));
            }
            Event::Text(t) => text.push_str(&t),
            Event::GeneralRef(r) => {
                text.push_str(match &*r {
                    "amp" => "&",
                    "lt" => "<",
                    "gt" => ">",
                    "quot" => "\"",
                    "apos" => "'",
                    other => panic!("unexpected entity {other}"),
                });
            }
            _ => {}
        }
    }
}

fn count(svg: &str, name: &str) -> usize {
    elements(svg).0.iter().filter(|(n, _)| n == name).count()
}

/// The `fill` of every polygon, in drawing order.
fn fills(svg: &str) -> Vec<String> {
    elements(svg)
        .0
        .into_iter()
        .filter(|(n, _)| n == "polygon")
        .map(|(_, a)| a.into_iter().find(|(k, _)| k == "fill").unwrap().1)
        .collect()
}

/// Every polygon corner, in pixels.
fn corners(svg: &str) -> Vec<[f64; 2]> {
    elements(svg)
        .0
        .into_iter()
        .filter(|(n, _)| n == "polygon")
        .flat_map(|(_, a)| {
            let pts = a.into_iter().find(|(k, _)| k == "points").unwrap().1;
            pts.split(' ')
                .map(|p| {
                    let (x, y) = p.split_once(',').unwrap();
                    [x.parse().unwrap(), y.parse().unwrap()]
                })
                .collect::<Vec<_>>()
        })
        .collect()
}

/// (width, height, RGBA pixels) of a PNG.
fn decode(bytes: &[u8]) -> (u32, u32, Vec<u8>) {
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgba);
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf)
}

fn pixel(img: &(u32, u32, Vec<u8>), x: u32, y: u32) -> [u8; 3] {
    let at = 4 * (y * img.0 + x) as usize;
    [img.2[at], img.2[at + 1], img.2[at + 2]]
}

const WHITE: [u8; 3] = [255, 255, 255];

#[test]
fn a_tetrahedron_is_four_polygons_and_its_points_are_dots() {
    let svg = mesh_svg(&TET_V, &TET_T, &[], &view()).unwrap();
    assert_eq!(count(&svg, "polygon"), 4);
    assert_eq!(count(&svg, "circle"), 0);
    assert_eq!(count(&svg, "text"), 0);
    assert!(svg.contains("width=\"320\" height=\"240\""));

    let samples = [[10.0, 10.0, 0.0], [0.0, 5.0, 5.0], [5.0, 0.0, 5.0]];
    let titled = MeshView {
        title: Some("PSR <d=8> & \"samples\"".into()),
        ..view()
    };
    let svg = mesh_svg(&TET_V, &TET_T, &samples, &titled).unwrap();
    assert_eq!(count(&svg, "polygon"), 4);
    assert_eq!(count(&svg, "circle"), 3);
    let (_, text) = elements(&svg);
    assert!(text.contains("PSR <d=8> & \"samples\""), "{text}");
    // Points alone (no triangles) are a picture too, fitted to the points.
    let svg = mesh_svg(&[], &[], &samples, &view()).unwrap();
    assert_eq!((count(&svg, "polygon"), count(&svg, "circle")), (0, 3));
    // Deterministic.
    assert_eq!(
        mesh_png(&TET_V, &TET_T, &samples, &titled).unwrap(),
        mesh_png(&TET_V, &TET_T, &samples, &titled).unwrap()
    );
}

#[test]
fn the_png_has_the_size_asked_the_mesh_in_the_middle_and_background_in_the_corners() {
    for (w, h) in [(320, 240), (100, 400), (640, 100)] {
        let v = MeshView {
            width: w,
            height: h,
            ..view()
        };
        let img = decode(&mesh_png(&TET_V, &TET_T, &[], &v).unwrap());
        assert_eq!((img.0, img.1), (w, h));
        // The tetrahedron's projected box is centred; the centroid of a face lies inside it.
        assert_ne!(pixel(&img, w / 2, h / 2), WHITE, "{w}×{h}");
        for (x, y) in [(0, 0), (w - 1, 0), (0, h - 1), (w - 1, h - 1)] {
            assert_eq!(pixel(&img, x, y), WHITE, "{w}×{h} at ({x}, {y})");
        }
    }
}

#[test]
fn faces_are_lit_by_a_head_light_back_faces_too_and_edge_on_faces_are_skipped() {
    // A unit cube seen along −y: front and back squares face the viewer (full colour), the four
    // sides are edge-on and not drawn.
    let v: Vec<[f64; 3]> = (0..8)
        .map(|i| [f64::from(i & 1), f64::from((i >> 1) & 1), f64::from(i >> 2)])
        .collect();
    let quads = [
        [0, 1, 3, 2],
        [4, 6, 7, 5],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 2, 6, 4],
        [1, 5, 7, 3],
    ];
    let t: Vec<[u32; 3]> = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    let grey = MeshView {
        colour: Colour::rgb(200, 100, 40),
        ..MeshView::anterior(200, 200)
    };
    let svg = mesh_svg(&v, &t, &[], &grey).unwrap();
    assert_eq!(fills(&svg), vec!["#c86428"; 4]);
    // Seen along a diagonal, every face is drawn, at 0.25 + 0.75 / √3 of the colour.
    let diagonal = MeshView {
        view_dir: [1.0, 1.0, 1.0],
        ..grey
    };
    let svg = mesh_svg(&v, &t, &[], &diagonal).unwrap();
    let k = 0.25 + 0.75 / 3f64.sqrt();
    let lit = |c: f64| (c * k).round() as u8;
    let want = format!("#{:02x}{:02x}{:02x}", lit(200.0), lit(100.0), lit(40.0));
    assert_eq!(fills(&svg), vec![want; 12]);
}

#[test]
fn the_nearer_triangle_is_drawn_last() {
    // Two triangles with the same projection, seen along −y: a far one facing the viewer (full
    // colour) at y = 0 and a near one tilted by 45° (darker), from y = 15 to −5.
    let v = [
        [-10.0, 0.0, -10.0],
        [10.0, 0.0, -10.0],
        [0.0, 0.0, 10.0],
        [-10.0, 15.0, -10.0],
        [10.0, 15.0, -10.0],
        [0.0, -5.0, 10.0],
    ];
    let view = MeshView::anterior(200, 200);
    let far_first = [[0, 1, 2], [3, 4, 5]];
    let near_first = [[3, 4, 5], [0, 1, 2]];
    let full = format!(
        "#{:02x}{:02x}{:02x}",
        view.colour.r, view.colour.g, view.colour.b
    );
    for t in [far_first, near_first] {
        let f = fills(&mesh_svg(&v, &t, &[], &view).unwrap());
        assert_eq!(f.len(), 2);
        assert_eq!(f[0], full, "the far triangle first");
        assert_ne!(f[1], full, "the near one, tilted, is darker");
        let img = decode(&mesh_png(&v, &t, &[], &view).unwrap());
        let centre = pixel(&img, 100, 100);
        assert!(
            i32::from(centre[0]) < i32::from(view.colour.r) - 20,
            "{centre:?}"
        );
    }
}

#[test]
fn panels_share_one_scale_and_lay_out_in_columns() {
    let big: Vec<[f64; 3]> = TET_V.iter().map(|p| p.map(|c| 2.0 * c)).collect();
    let panel = |vertices, title| MeshPanel {
        vertices,
        triangles: &TET_T,
        points: &[],
        title,
    };
    let panels = [
        panel(&TET_V[..], Some("small")),
        panel(&big[..], Some("big")),
        panel(&TET_V[..], None),
    ];
    let v = view();
    let svg = mesh_panel_svg(&panels, &v, 2).unwrap();
    assert_eq!(count(&svg, "polygon"), 12);
    assert_eq!(count(&svg, "text"), 2);
    assert!(svg.contains("width=\"640\" height=\"480\""));
    // Each mesh's width on the picture: the big one is twice the small one.
    let pts = corners(&svg);
    let span = |cell: std::ops::Range<f64>| {
        let xs: Vec<f64> = pts
            .iter()
            .filter(|p| cell.contains(&p[0]) && p[1] < 240.0)
            .map(|p| p[0])
            .collect();
        xs.iter().copied().fold(f64::MIN, f64::max) - xs.iter().copied().fold(f64::MAX, f64::min)
    };
    let (small, large) = (span(0.0..320.0), span(320.0..640.0));
    assert!((large / small - 2.0).abs() < 0.01, "{small} {large}");

    // A caption adds a band above the cells; more columns than panels make one row.
    let captioned = MeshView {
        title: Some("Reconstructions".into()),
        ..view()
    };
    let img = decode(&mesh_panel_png(&panels, &captioned, 5).unwrap());
    assert_eq!(img.0, 960);
    assert!(img.1 > 240 && img.1 < 300, "{}", img.1);
    let svg = mesh_panel_svg(&panels, &captioned, 5).unwrap();
    assert!(elements(&svg).1.contains("Reconstructions"));
    // A panel with nothing to draw leaves its cell empty.
    let empty = MeshPanel {
        vertices: &[],
        triangles: &[],
        points: &[],
        title: Some("none"),
    };
    let svg = mesh_panel_svg(&[panels[0], empty], &v, 2).unwrap();
    assert_eq!(count(&svg, "polygon"), 4);
}

#[test]
fn bad_input_is_a_plot_error() {
    let v = view();
    let bad_tri = [[0, 1, 2], [1, 2, 4]];
    assert_eq!(
        mesh_svg(&TET_V, &bad_tri, &[], &v),
        Err(PlotError::VertexIndex {
            mesh: 0,
            triangle: 1,
            index: 4,
            vertices: 4
        })
    );
    let mut nan = TET_V;
    nan[2][1] = f64::NAN;
    assert_eq!(
        mesh_png(&nan, &TET_T, &[], &v),
        Err(PlotError::NonFiniteCoordinate {
            mesh: 0,
            what: "vertex",
            index: 2
        })
    );
    assert_eq!(
        mesh_svg(&TET_V, &TET_T, &[[0.0, f64::INFINITY, 0.0]], &v),
        Err(PlotError::NonFiniteCoordinate {
            mesh: 0,
            what: "point",
            index: 0
        })
    );
    assert_eq!(mesh_svg(&[], &[], &[], &v), Err(PlotError::NoData));
    assert_eq!(mesh_svg(&TET_V, &[], &[], &v), Err(PlotError::NoData));
    assert_eq!(mesh_panel_svg(&[], &v, 2), Err(PlotError::NoData));

    for bad in [
        MeshView {
            view_dir: [0.0; 3],
            ..view()
        },
        MeshView {
            view_dir: [f64::NAN, 1.0, 0.0],
            ..view()
        },
        MeshView {
            up: [0.0; 3],
            ..view()
        },
        MeshView {
            up: [2.0, 1.4, 0.8],
            ..view()
        },
        MeshView {
            point_radius: -1.0,
            ..view()
        },
        MeshView {
            point_radius: f64::NAN,
            ..view()
        },
    ] {
        let e = mesh_png(&TET_V, &TET_T, &[], &bad).unwrap_err();
        assert!(matches!(e, PlotError::BadView(_)), "{bad:?}: {e}");
        assert!(e.to_string().starts_with("bad view: "));
    }
    for (w, h) in [(0, 240), (320, 0), (99, 240), (320, 4097)] {
        let bad = MeshView {
            width: w,
            height: h,
            ..view()
        };
        assert_eq!(
            mesh_png(&TET_V, &TET_T, &[], &bad),
            Err(PlotError::BadSize {
                width: w,
                height: h
            })
        );
    }
    let panels = [MeshPanel {
        vertices: &TET_V,
        triangles: &TET_T,
        points: &[],
        title: None,
    }; 13];
    assert!(matches!(
        mesh_panel_png(&panels, &v, 0),
        Err(PlotError::BadView(_))
    ));
    assert_eq!(
        mesh_panel_png(&panels, &v, 13),
        Err(PlotError::BadSize {
            width: 13 * 320,
            height: 240
        })
    );
    let mut panels = panels.to_vec();
    panels[1].triangles = &bad_tri;
    assert!(matches!(
        mesh_panel_svg(&panels, &v, 4),
        Err(PlotError::VertexIndex { mesh: 1, .. })
    ));
}

/// A UV sphere of radius `r` with `n` × `2n` quads (`4n²` triangles).
fn sphere(r: f64, n: u32) -> (Vec<[f64; 3]>, Vec<[u32; 3]>) {
    let m = 2 * n;
    let mut v = Vec::new();
    for i in 0..=n {
        let theta = std::f64::consts::PI * f64::from(i) / f64::from(n);
        for j in 0..m {
            let phi = std::f64::consts::TAU * f64::from(j) / f64::from(m);
            v.push([
                r * theta.sin() * phi.cos(),
                r * theta.sin() * phi.sin(),
                r * theta.cos(),
            ]);
        }
    }
    let id = |i: u32, j: u32| i * m + j % m;
    let mut t = Vec::new();
    for i in 0..n {
        for j in 0..m {
            t.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            t.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    (v, t)
}

#[test]
fn a_fifty_thousand_triangle_sphere_draws_as_a_disc() {
    let (v, t) = sphere(50.0, 112);
    assert!(t.len() > 50_000);
    let view = MeshView::anterior(400, 400);
    let start = std::time::Instant::now();
    let img = decode(&mesh_png(&v, &t, &[], &view).unwrap());
    eprintln!(
        "{} triangles: PNG in {:.0} ms",
        t.len(),
        start.elapsed().as_secs_f64() * 1e3
    );
    // Lit head-on in the middle, darker towards the rim, background outside the disc.
    let c = view.colour;
    let centre = pixel(&img, 200, 200);
    assert!(
        centre
            .iter()
            .zip([c.r, c.g, c.b])
            .all(|(&a, b)| a.abs_diff(b) <= 3),
        "{centre:?}"
    );
    let rim = pixel(&img, 200, 200 - 175);
    assert!(rim[0] < centre[0] - 40, "{rim:?}");
    assert_eq!(pixel(&img, 10, 10), WHITE);
    // No background shows through seams inside the disc.
    let mut seams = 0;
    for y in (40..360).step_by(3) {
        for x in (40..360).step_by(3) {
            let (dx, dy) = (f64::from(x) - 200.0, f64::from(y) - 200.0);
            if dx.hypot(dy) < 170.0 && pixel(&img, x, y)[1] > 200 {
                seams += 1;
            }
        }
    }
    assert_eq!(seams, 0);
}
