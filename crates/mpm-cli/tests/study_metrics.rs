//! `mpm study` (`mpm_cli::study`): `--vary` arguments, combinations, nearest
//! particles and history interpolation.

use mpm_cli::study::{combinations, interpolate, nearest, parse_vary, rms_history};

#[test]
fn vary_arguments_split_outside_brackets() {
    let (k, v) = parse_vary("body.0.velocity=[0,-1],[0, -2]").unwrap();
    assert_eq!(k, "body.0.velocity");
    assert_eq!(v, vec!["[0,-1]", "[0, -2]"]);
    assert!(parse_vary("simulation.h").is_err());
    assert!(parse_vary("simulation.h=0.1,").is_err());
    let combos = combinations(&[
        ("a".into(), vec!["1".into(), "2".into()]),
        ("b".into(), vec!["x".into(), "y".into(), "z".into()]),
    ]);
    assert_eq!(combos.len(), 6);
    assert_eq!(combos[1], vec!["1", "y"]);
}

#[test]
fn nearest_and_interpolation() {
    let reference: Vec<[f64; 3]> = (0..100)
        .map(|i| [(i % 10) as f64 * 0.1, (i / 10) as f64 * 0.1, 0.0])
        .collect();
    let points = [[0.31, 0.52, 0.0], [0.0, 0.0, 0.0], [5.0, 5.0, 0.0]];
    assert_eq!(nearest(&reference, &points, 0.1), vec![53, 0, 99]);
    let t = [0.0, 1.0, 2.0];
    let v = [0.0, 10.0, 0.0];
    assert_eq!(interpolate(&t, &v, 0.5), 5.0);
    assert_eq!(interpolate(&t, &v, 3.0), 0.0);
    assert_eq!(rms_history(&t, &v, &t, &v), 0.0);
}
