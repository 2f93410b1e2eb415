//! SVG and PNG output of figures, bad input, and the Pareto figure of a study.
#![allow(clippy::unwrap_used)] // test helpers

use quick_xml::Reader;
use quick_xml::events::Event;
use resecta_meshmetrics::{ModelMethod, ModelRecord, analyse};
use resecta_plot::{Colour, Figure, MarkerShape, PlotError, Series, Style, pareto_figure};

fn figure(log_x: bool) -> Figure {
    let curve: Vec<(f64, f64)> = (1..=20)
        .map(|i| (i as f64 * 50.0, 10.0 / i as f64))
        .collect();
    Figure {
        title: "Test figure".into(),
        x_label: "Voxels".into(),
        y_label: "Time (ms)".into(),
        log_x,
        series: vec![
            Series::new(
                "scatter-blue",
                curve.clone(),
                Style::Markers {
                    shape: MarkerShape::Square,
                    colour: Colour::BLUE,
                },
            ),
            Series::new(
                "line-black",
                curve.clone(),
                Style::Line {
                    colour: Colour::BLACK,
                },
            ),
            Series {
                labels: vec![Some("best".into()), None],
                ..Series::new(
                    "picked-red",
                    vec![curve[3], curve[9]],
                    Style::HighlightedMarkers {
                        shape: MarkerShape::Cross,
                        colour: Colour::RED,
                    },
                )
            },
        ],
        width: 640,
        height: 480,
    }
}

/// Number of XML elements; panics if the text is not well-formed.
// quick_xml's other events (text, comments, ...) are not counted; listing them adds nothing.
#[allow(clippy::wildcard_enum_match_arm)]
fn parse_xml(text: &str) -> usize {
    let mut reader = Reader::from_str(text);
    let mut elements = 0;
    loop {
        match reader.read_event().unwrap() {
            Event::Eof => return elements,
            Event::Start(_) | Event::Empty(_) => elements += 1,
            _ => {}
        }
    }
}

/// Decodes a PNG: (width, height, RGBA or RGB pixels, channels).
fn decode_png(bytes: &[u8]) -> (u32, u32, Vec<u8>, usize) {
    let decoder = png::Decoder::new(std::io::Cursor::new(bytes));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader.next_frame(&mut buf).unwrap();
    buf.truncate(info.buffer_size());
    (info.width, info.height, buf, info.color_type.samples())
}

#[test]
fn svg_is_xml_with_names_and_labels() {
    for log_x in [false, true] {
        let svg = figure(log_x).to_svg().unwrap();
        assert!(parse_xml(&svg) > 50, "markers, lines and text are elements");
        for text in [
            "Test figure",
            "Voxels",
            "Time (ms)",
            "scatter-blue",
            "line-black",
            "picked-red",
            "\nbest\n",
        ] {
            assert!(svg.contains(text), "{text} missing (log_x = {log_x})");
        }
        assert!(svg.contains(r#"width="640""#) && svg.contains(r#"height="480""#));
    }
}

#[test]
fn png_decodes_with_size_and_content() {
    let bytes = figure(true).to_png().unwrap();
    let (w, h, px, ch) = decode_png(&bytes);
    assert_eq!((w, h), (640, 480));
    assert!(ch >= 3);
    let pixels: Vec<&[u8]> = px.chunks(ch).collect();
    assert_eq!(pixels.len(), 640 * 480);
    // White background and the light grey grid.
    let white = pixels
        .iter()
        .filter(|p| p[..3].iter().all(|&c| c >= 230))
        .count();
    let dark = pixels
        .iter()
        .filter(|p| p[..3].iter().all(|&c| c < 60))
        .count();
    // Highlighted red cross: pure fill colour.
    let red = pixels.iter().filter(|p| p[..3] == [214, 39, 40]).count();
    let bluish = pixels
        .iter()
        .filter(|p| p[2] > 150 && p[0] < 130 && p[1] < 180)
        .count();
    assert!(white > pixels.len() / 2, "mostly background: {white}");
    assert!(dark > 800, "axes, line and text are drawn: {dark}");
    assert!(red > 30, "highlighted markers: {red}");
    assert!(bluish > 200, "blue markers: {bluish}");
}

#[test]
fn output_is_deterministic() {
    let f = figure(false);
    assert_eq!(f.to_svg().unwrap(), f.to_svg().unwrap());
    assert_eq!(f.to_png().unwrap(), f.to_png().unwrap());
}

#[test]
fn bad_figures_are_errors() {
    let mut f = figure(false);
    for s in &mut f.series {
        s.points.clear();
        s.labels.clear();
    }
    assert_eq!(f.to_svg(), Err(PlotError::NoData));
    assert_eq!(f.to_png(), Err(PlotError::NoData));
    let mut f = figure(false);
    f.series.clear();
    assert_eq!(f.to_png(), Err(PlotError::NoData));

    let mut f = figure(false);
    f.series[1].points[4].1 = f64::NAN;
    assert_eq!(
        f.to_svg(),
        Err(PlotError::NonFinite {
            series: "line-black".into(),
            index: 4
        })
    );
    let mut f = figure(false);
    f.series[0].points[0].0 = f64::INFINITY;
    assert!(matches!(
        f.to_png(),
        Err(PlotError::NonFinite { index: 0, .. })
    ));

    let mut f = figure(true);
    f.series[0].points[2].0 = 0.0;
    assert!(matches!(
        f.to_svg(),
        Err(PlotError::NonPositiveLogX { index: 2, .. })
    ));
    f.log_x = false;
    assert!(f.to_svg().is_ok(), "zero is fine on a linear axis");

    let mut f = figure(false);
    f.series[2].labels.push(None);
    assert!(matches!(
        f.to_svg(),
        Err(PlotError::LabelCount {
            labels: 3,
            points: 2,
            ..
        })
    ));

    for (w, h) in [(0, 480), (640, 99), (5000, 480)] {
        let mut f = figure(false);
        (f.width, f.height) = (w, h);
        assert_eq!(
            f.to_png(),
            Err(PlotError::BadSize {
                width: w,
                height: h
            })
        );
    }
}

/// A single point (flat ranges on both axes) still draws.
#[test]
fn single_point_draws() {
    let f = Figure {
        series: vec![Series::new(
            "one",
            vec![(5.0, 5.0)],
            Style::Markers {
                shape: MarkerShape::Circle,
                colour: Colour::GREEN,
            },
        )],
        ..figure(true)
    };
    assert!(f.to_svg().unwrap().contains("one"));
    assert_eq!(decode_png(&f.to_png().unwrap()).0, 640);
}

fn rec(label: &str, method: ModelMethod, polys: usize, mean: f64, k: f64) -> ModelRecord {
    ModelRecord {
        label: label.into(),
        method,
        polys,
        points: polys / 2,
        mean_mm: mean,
        p95_mm: 2.0 * mean,
        max_mm: 4.0 * mean,
        curvature: k,
        time_ms: 10.0,
    }
}

#[test]
fn pareto_figure_of_a_study() {
    let mcsd = |s, e| ModelMethod::Mcsd {
        smoothing: s,
        decimation: e,
    };
    let records = vec![
        rec("p5", ModelMethod::Psr { depth: 5 }, 4_000, 3.7, 4e-3),
        rec("p7", ModelMethod::Psr { depth: 7 }, 62_000, 1.1, 2e-4),
        rec("m1", mcsd(0.0, 0.0), 600_000, 0.6, 2e-3),
        rec("m2", mcsd(45.0, 0.8), 90_000, 1.0, 3e-4),
        rec("m3", mcsd(90.0, 0.5), 200_000, 1.3, 5e-2),
        rec(
            "ext",
            ModelMethod::External {
                name: "Slicer".into(),
            },
            500_000,
            0.7,
            1e-3,
        ),
    ];
    let study = analyse(records).unwrap();
    // m2 is both the best MCSD and the MCSD closest in curvature to p7.
    assert_eq!(
        (study.p_best, study.c_best, study.c_sim),
        (Some(1), Some(3), Some(3))
    );
    let fig = pareto_figure(&study);
    assert!(fig.log_x);
    let names: Vec<&str> = fig.series.iter().map(|s| s.name.as_str()).collect();
    assert_eq!(
        names,
        [
            "PSR",
            "MCSD",
            "Slicer",
            "Pareto front",
            "∂P_best: PSR d = 7",
            "∂C_best = ∂C_sim: MCSD s = 45, e = 0.8",
        ]
    );
    let psr = &fig.series[0];
    assert_eq!(psr.labels, [Some("d = 5".to_owned()), None]);
    let front = &fig.series[3].points;
    assert!(front.windows(2).all(|w| w[0].0 <= w[1].0));
    assert_eq!(front.len(), study.pareto_front.len());
    assert_eq!(fig.series[5].points, [(90_000.0, 1.0)]);
    let svg = fig.to_svg().unwrap();
    parse_xml(&svg);
    assert!(svg.contains("∂C_best = ∂C_sim") && svg.contains("Polygons"));
    let (w, h, _, _) = decode_png(&fig.to_png().unwrap());
    assert_eq!((w, h), (fig.width, fig.height));
}
