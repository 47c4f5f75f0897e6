//! `mpm plot` (`mpm_cli::plot`): stats.csv parsing.

use mpm_cli::plot::StatsTable;

#[test]
fn stats_table_parses_and_names_bad_lines() {
    let t = StatsTable::parse("time,a\n0,1\n0.5,2e0\n", "s.csv").unwrap();
    assert_eq!(t.rows(), 2);
    assert_eq!(t.column("a"), Some(&[1.0, 2.0][..]));
    assert!(t.column("b").is_none());
    let e = StatsTable::parse("time,a\n0,1\n0.5\n", "s.csv").unwrap_err();
    assert_eq!(e.to_string(), "s.csv: line 3: 1 fields, the header has 2");
    let e = StatsTable::parse("time,a\n0,x\n", "s.csv").unwrap_err();
    assert_eq!(
        e.to_string(),
        "s.csv: line 2: `x` is not a number (column a)"
    );
    assert!(StatsTable::parse("", "s.csv").is_err());
}
