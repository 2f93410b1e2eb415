//! Objective score, selection of the best models and the Pareto front on hand-made records.

use resecta_meshmetrics::{MetricsError, ModelMethod, ModelRecord, Study, analyse, pareto_front};

fn rec(label: &str, method: ModelMethod, polys: usize, mean: f64, curvature: f64) -> ModelRecord {
    ModelRecord {
        label: label.into(),
        method,
        polys,
        points: polys / 2 + 2,
        mean_mm: mean,
        p95_mm: 2.0 * mean,
        max_mm: 3.0 * mean,
        curvature,
        time_ms: 100.0,
    }
}

fn psr(d: u32) -> ModelMethod {
    ModelMethod::Psr { depth: d }
}

fn mcsd(s: f64, e: f64) -> ModelMethod {
    ModelMethod::Mcsd {
        smoothing: s,
        decimation: e,
    }
}

/// Polygons span 10 K..410 K (range 400 K), mean errors 0.6..4.0 mm (range 3.4 mm).
fn records() -> Vec<ModelRecord> {
    vec![
        rec("G", mcsd(90.0, 0.9), 50_000, 2.5, 0.03),   // 0
        rec("E", mcsd(0.0, 0.0), 410_000, 0.6, 0.0025), // 1
        rec("A", psr(5), 10_000, 4.0, 0.010),           // 2
        rec("F", mcsd(45.0, 0.5), 110_000, 1.2, 0.05),  // 3
        rec("C", psr(7), 70_000, 1.0, 0.002),           // 4
        rec("B", psr(6), 30_000, 2.0, 0.004),           // 5
        rec("D", psr(8), 250_000, 0.8, 0.001),          // 6
    ]
}

/// Hand-computed: N̂ = (N − 10 K)/400 K, δ̂ = (δ̄ − 0.6)/3.4, σ = √(δ̂² + N̂²).
#[test]
fn scores_and_selection_match_hand_computation() {
    let s = analyse(records()).unwrap();
    let expected = [
        (40.0 / 400.0, 1.9 / 3.4),
        (1.0, 0.0),
        (0.0, 1.0),
        (100.0 / 400.0, 0.6 / 3.4),
        (60.0 / 400.0, 0.4 / 3.4),
        (20.0 / 400.0, 1.4 / 3.4),
        (240.0 / 400.0, 0.2 / 3.4),
    ];
    for (m, (n, d)) in s.models.iter().zip(expected) {
        assert!((m.n_hat - n).abs() < 1e-12, "{}", m.record.label);
        assert!((m.delta_hat - d).abs() < 1e-12, "{}", m.record.label);
        assert!((m.sigma - (n * n + d * d).sqrt()).abs() < 1e-12);
    }
    // σ: C 0.1906, F 0.3060, B 0.4148, G 0.5677, D 0.6029, A = E = 1.
    assert!((s.models[4].sigma - 0.190_632_7).abs() < 1e-6);
    assert_eq!(s.p_best, Some(4)); // C, d = 7
    assert_eq!(s.c_best, Some(3)); // F
    assert_eq!(s.m_best, 4);
    // |K − K(C)| = |K − 0.002|: G 0.028, E 0.0005, F 0.048 → E.
    assert_eq!(s.c_sim, Some(1));
    // By polygons: A(10K, 4.0) B(30K, 2.0) [G(50K, 2.5) dominated by B] C(70K, 1.0)
    // [F(110K, 1.2) dominated by C] D(250K, 0.8) E(410K, 0.6).
    assert_eq!(s.pareto_front, vec![2, 5, 4, 6, 1]);
    let flags: Vec<bool> = s.models.iter().map(|m| m.pareto).collect();
    assert_eq!(flags, [false, true, true, false, true, true, true]);
    assert_eq!(s.model(s.c_sim).unwrap().record.label, "E");
    assert!(s.model(None).is_none());
}

#[test]
fn all_equal_values_normalise_to_zero() {
    let recs = vec![
        rec("a", psr(7), 1000, 1.0, 0.1),
        rec("b", mcsd(0.0, 0.0), 1000, 1.0, 0.1),
    ];
    let s = analyse(recs).unwrap();
    for m in &s.models {
        assert_eq!((m.n_hat, m.delta_hat, m.sigma), (0.0, 0.0, 0.0));
        assert!(m.pareto, "exact duplicates are both on the front");
    }
    assert_eq!(s.m_best, 0, "ties go to the first model");
    assert_eq!((s.p_best, s.c_best, s.c_sim), (Some(0), Some(1), Some(1)));
    // A single record is its own best.
    let s = analyse(vec![rec("only", psr(5), 5, 0.5, 0.0)]).unwrap();
    assert_eq!((s.m_best, s.p_best, s.c_best), (0, Some(0), None));
    assert_eq!(s.models[0].sigma, 0.0);
}

#[test]
fn missing_groups_give_none() {
    // σ: 1, √((1/6)² + 0.25²) ≈ 0.30, 1.
    let only_psr = vec![
        rec("5", psr(5), 10, 3.0, 0.1),
        rec("6", psr(6), 20, 1.5, 0.1),
        rec("7", psr(7), 70, 1.0, 0.1),
    ];
    let s = analyse(only_psr).unwrap();
    assert_eq!((s.p_best, s.c_best, s.c_sim), (Some(1), None, None));
    let only_mcsd = vec![rec("x", mcsd(0.0, 0.5), 10, 3.0, 0.1)];
    let s = analyse(only_mcsd).unwrap();
    assert_eq!((s.p_best, s.c_best, s.c_sim), (None, Some(0), None));
    let ext = vec![rec(
        "slicer",
        ModelMethod::External {
            name: "Slicer".into(),
        },
        10,
        1.0,
        0.0,
    )];
    let s = analyse(ext).unwrap();
    assert_eq!(
        (s.p_best, s.c_best, s.c_sim, s.m_best),
        (None, None, None, 0)
    );
    assert!(s.markdown().contains("No PSR or MCSD models."));
}

#[test]
fn bad_records_are_errors() {
    assert_eq!(analyse(vec![]), Err(MetricsError::NoRecords));
    let mut r = records();
    r[3].mean_mm = f64::NAN;
    assert_eq!(
        analyse(r),
        Err(MetricsError::BadRecord {
            label: "F".into(),
            field: "mean_mm"
        })
    );
    let mut r = records();
    r[0].curvature = f64::INFINITY;
    assert!(matches!(
        analyse(r),
        Err(MetricsError::BadRecord {
            field: "curvature",
            ..
        })
    ));
    let mut r = records();
    r[2].time_ms = -1.0;
    assert!(matches!(
        analyse(r),
        Err(MetricsError::BadRecord {
            field: "time_ms",
            ..
        })
    ));
    let mut r = records();
    r[1].method = mcsd(f64::NAN, 0.1);
    assert!(matches!(
        analyse(r),
        Err(MetricsError::BadRecord {
            field: "smoothing",
            ..
        })
    ));
    let mut r = records();
    r[1].label = "A".into();
    assert_eq!(analyse(r), Err(MetricsError::DuplicateLabel("A".into())));
}

#[test]
fn pareto_front_edge_cases() {
    assert!(pareto_front(&[]).is_empty());
    assert_eq!(pareto_front(&[(1.0, 1.0)]), vec![0]);
    // Same x: only the lower y; exact duplicates both; NaN never.
    let pts = [
        (2.0, 5.0),
        (2.0, 3.0),
        (1.0, 4.0),
        (1.0, 4.0),
        (f64::NAN, 0.0),
        (3.0, 3.0),
    ];
    assert_eq!(pareto_front(&pts), vec![2, 3, 1]);
    // A strictly decreasing staircase is entirely on the front, sorted by x.
    let stairs: Vec<(f64, f64)> = (0..50).rev().map(|i| (i as f64, -(i as f64))).collect();
    let front = pareto_front(&stairs);
    assert_eq!(front, (0..50).rev().collect::<Vec<_>>());
}

#[test]
fn json_round_trip_and_determinism() {
    let s = analyse(records()).unwrap();
    let json = serde_json::to_string(&s).unwrap();
    assert!(json.contains(r#""kind":"psr","depth":7"#), "{json}");
    let back: Study = serde_json::from_str(&json).unwrap();
    // serde_json's default parser may be 1 ulp off on some decimals; all else is exact.
    assert_eq!(back.pareto_front, s.pareto_front);
    assert_eq!(
        (back.p_best, back.c_best, back.m_best, back.c_sim),
        (s.p_best, s.c_best, s.m_best, s.c_sim)
    );
    for (a, b) in back.models.iter().zip(&s.models) {
        assert_eq!(a.record, b.record);
        assert_eq!(a.pareto, b.pareto);
        for (x, y) in [
            (a.sigma, b.sigma),
            (a.n_hat, b.n_hat),
            (a.delta_hat, b.delta_hat),
        ] {
            assert!((x - y).abs() <= 1e-15, "{x} vs {y}");
        }
    }
    assert_eq!(analyse(records()).unwrap(), s);
}

#[test]
fn markdown_tables() {
    let s = analyse(records()).unwrap();
    let md = s.markdown();
    // Table 6.2: PSR by depth, then the best MCSD; least σ (d = 7) in bold.
    assert!(md.contains(
        "|  | PSR d = 5 | PSR d = 6 | PSR d = 7 | PSR d = 8 | Best MCSD (MCSD s = 45, e = 0.5) |"
    ), "{md}");
    assert!(
        md.contains("| σ | 1.000 | 0.415 | **0.191** | 0.603 | 0.306 |"),
        "{md}"
    );
    // Table 6.3: P_best, C_sim, C_best.
    assert!(
        md.contains("| Polygons (K) | **70.0** | 410.0 | 110.0 |"),
        "{md}"
    );
    assert!(
        md.contains("| Mean error (mm) | 1.00 | **0.60** | 1.20 |"),
        "{md}"
    );
    // Table 6.4 in 1e-3 mm⁻², least |K̄| in bold (d = 8).
    assert!(
        md.contains("| K̄ | 10.00 | 4.00 | 2.00 | **1.00** | 2.50 | 50.00 |"),
        "{md}"
    );
    // Full table: one row per model with its selection tags.
    assert!(md.contains("| C | PSR d = 7 | 70000 |"));
    assert!(md.contains("| yes | ∂M_best, ∂P_best |"));
    assert!(md.contains("| yes | ∂C_sim |"));
    // Header and rows: 2 (6.2) + 4 (6.3) + 2 (6.4) + 8 (all models).
    let rows = md
        .lines()
        .filter(|l| l.starts_with('|') && !l.starts_with("|---"));
    assert_eq!(rows.count(), 16);
}
