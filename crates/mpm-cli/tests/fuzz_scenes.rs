//! Fuzzed scene input: mutated copies of every shipped scene (deleted, duplicated and
//! retyped keys, extreme and non-finite numbers, wrong units, broken TOML, huge
//! particle counts, wrong array lengths) go through the parser and validator that
//! `mpm validate` and `mpm run` use. No mutation may panic; every refusal must name
//! the file, and a refused key must be named by its dotted path with a fix that says
//! what is allowed.
//!
//! `cargo test` runs `MPM_FUZZ_CASES` cases (default 10,000, about ten seconds);
//! `MPM_FUZZ_CASES=1000000 MPM_FUZZ_SEED=7 cargo test --release -p mpm-cli --test
//! fuzz_scenes` is the long run.

use mpm_cli::scene::{parse_scene_in, SceneError};
use std::panic::AssertUnwindSafe;
use std::path::PathBuf;
use toml::{Table, Value};

struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
    fn pick<'a, T>(&mut self, items: &'a [T]) -> &'a T {
        &items[self.below(items.len())]
    }
}

fn scenes_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scenes")
}

fn shipped() -> Vec<(String, String)> {
    let mut v: Vec<(String, String)> = std::fs::read_dir(scenes_dir())
        .unwrap()
        .filter_map(|e| {
            let p = e.ok()?.path();
            (p.extension()? == "toml").then(|| {
                (
                    p.file_name().unwrap().to_string_lossy().into_owned(),
                    std::fs::read_to_string(&p).unwrap(),
                )
            })
        })
        .collect();
    v.sort();
    assert!(v.len() >= 10, "shipped scenes not found");
    v
}

/// Every dotted path to a leaf (arrays of tables indexed: `body.0.shape.radius`).
fn leaf_paths(v: &Value, prefix: &str, out: &mut Vec<String>) {
    let join = |k: &str| {
        if prefix.is_empty() {
            k.to_string()
        } else {
            format!("{prefix}.{k}")
        }
    };
    match v {
        Value::Table(t) => {
            for (k, x) in t {
                out.push(join(k));
                leaf_paths(x, &join(k), out);
            }
        }
        Value::Array(a) if a.iter().any(|x| x.is_table()) => {
            for (i, x) in a.iter().enumerate() {
                leaf_paths(x, &join(&i.to_string()), out);
            }
        }
        _ => {}
    }
}

/// The value at `path`, mutably, with its parent container.
fn at<'a>(root: &'a mut Value, path: &str) -> Option<&'a mut Value> {
    let mut cur = root;
    for part in path.split('.') {
        cur = match cur {
            Value::Table(t) => t.get_mut(part)?,
            Value::Array(a) => a.get_mut(part.parse::<usize>().ok()?)?,
            _ => return None,
        };
    }
    Some(cur)
}

fn remove(root: &mut Value, path: &str) {
    let (parent, last) = match path.rsplit_once('.') {
        Some((p, l)) => (at(root, p), l),
        None => (Some(root), path),
    };
    match parent {
        Some(Value::Table(t)) => {
            t.remove(last);
        }
        Some(Value::Array(a)) => {
            if let Ok(i) = last.parse::<usize>() {
                if i < a.len() {
                    a.remove(i);
                }
            }
        }
        _ => {}
    }
}

fn extreme_number(rng: &mut Rng) -> Value {
    let floats = [
        0.0,
        -0.0,
        -1.0,
        1e-308,
        5e-324,
        1e308,
        -1e308,
        f64::MAX,
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        1e-12,
        1e12,
        0.5,
        2.0,
    ];
    let ints = [
        0i64,
        -1,
        1,
        i64::MAX,
        i64::MIN,
        65_536,
        4_294_967_297,
        1_000_000_000,
    ];
    if rng.below(3) == 0 {
        Value::Integer(*rng.pick(&ints))
    } else {
        Value::Float(*rng.pick(&floats))
    }
}

fn other_type(rng: &mut Rng, v: &Value) -> Value {
    let choices = [
        Value::String("twelve".into()),
        Value::String(String::new()),
        Value::Boolean(true),
        Value::Integer(3),
        Value::Float(0.25),
        Value::Array(vec![]),
        Value::Array(vec![Value::Float(1.0); 7]),
        Value::Array(vec![Value::String("x".into())]),
        Value::Table(Table::new()),
    ];
    loop {
        let c = rng.pick(&choices).clone();
        if c.type_str() != v.type_str() {
            return c;
        }
    }
}

/// One structural mutation of the parsed document.
fn mutate_value(rng: &mut Rng, doc: &mut Value) {
    let mut paths = Vec::new();
    leaf_paths(doc, "", &mut paths);
    let path = rng.pick(&paths).clone();
    match rng.below(9) {
        0 => remove(doc, &path),
        1 => {
            if let Some(v) = at(doc, &path) {
                *v = other_type(rng, v);
            }
        }
        2 | 3 => {
            if let Some(v) = at(doc, &path) {
                match v {
                    Value::Array(a) if !a.is_empty() && !a[0].is_table() => {
                        let i = rng.below(a.len());
                        a[i] = extreme_number(rng);
                    }
                    _ => *v = extreme_number(rng),
                }
            }
        }
        4 => {
            // Wrong units: millimetres for metres, MPa for Pa, or a unit in the string.
            if let Some(v) = at(doc, &path) {
                let changed = match &*v {
                    Value::Float(x) => Value::Float(*x * *rng.pick(&[1e3, 1e-3, 1e6, 1e-6])),
                    Value::Integer(x) => Value::Integer(x.saturating_mul(1000)),
                    other => Value::String(format!("{other} m")),
                };
                *v = changed;
            }
        }
        5 => {
            // Arrays one element short or long.
            if let Some(Value::Array(a)) = at(doc, &path) {
                if rng.below(2) == 0 {
                    a.pop();
                } else {
                    a.push(Value::Float(0.5));
                }
            }
        }
        6 => {
            // Huge particle counts.
            match rng.below(3) {
                0 => {
                    if let Some(v) = at(doc, "simulation.h") {
                        *v = Value::Float(*rng.pick(&[1e-5, 1e-7, 1e-12, 1e-300]));
                    }
                }
                1 => {
                    if let Some(Value::Table(b)) = at(doc, "body.0") {
                        b.insert(
                            "particles_per_cell".into(),
                            Value::Integer(*rng.pick(&[1000, 1_000_000, i64::MAX])),
                        );
                    }
                }
                _ => {
                    if let Some(Value::Table(t)) = at(doc, "simulation") {
                        t.insert(
                            "domain_max".into(),
                            Value::Array(vec![Value::Float(1e9); 3]),
                        );
                    }
                }
            }
        }
        7 => {
            // An unknown key beside a known one.
            let parent = path.rsplit_once('.').map_or("", |(p, _)| p);
            let target = if parent.is_empty() {
                Some(&mut *doc)
            } else {
                at(doc, parent)
            };
            if let Some(Value::Table(t)) = target {
                t.insert("youngs_modulos".into(), Value::Float(1e5));
            }
        }
        _ => {
            // Duplicate a [[body]] or [[material]] entry, or drop them all.
            let key = *rng.pick(&["body", "material", "probe", "collider"]);
            if let Some(Value::Array(a)) = at(doc, key) {
                if rng.below(3) == 0 {
                    a.clear();
                } else if let Some(first) = a.first().cloned() {
                    a.push(first);
                }
            }
        }
    }
}

/// One textual mutation (what a structural edit cannot produce: broken syntax,
/// duplicated keys).
fn mutate_text(rng: &mut Rng, text: &str) -> String {
    let lines: Vec<&str> = text.lines().collect();
    let i = rng.below(lines.len());
    match rng.below(5) {
        0 => {
            // Truncated (at a character boundary: the file is still UTF-8).
            let mut end = text.len() * rng.below(100) / 100;
            while !text.is_char_boundary(end) {
                end -= 1;
            }
            text[..end].to_string()
        }
        1 => {
            // A duplicated key line.
            let mut out = lines.clone();
            out.insert(i, lines[i]);
            out.join("\n")
        }
        2 => {
            // A stray or missing bracket, quote or equals sign.
            let mut line = lines[i].to_string();
            let junk = *rng.pick(&["[", "]", "\"", "=", "{", "}", ",", "'''", "\u{0}", "é"]);
            let at = rng.below(line.len() + 1);
            if line.is_char_boundary(at) {
                line.insert_str(at, junk);
            }
            let mut out = lines.clone();
            out[i] = &line;
            out.join("\n")
        }
        3 => {
            let mut out = lines.clone();
            out.remove(i);
            out.join("\n")
        }
        _ => format!("{text}\n[simulation]\ndim = 3\n"),
    }
}

fn check_error(e: &SceneError, origin: &str, case: &str) {
    let msg = e.to_string();
    assert!(
        msg.starts_with(origin),
        "error without the file name: {msg}\n{case}"
    );
    match e {
        SceneError::Invalid {
            key, problem, fix, ..
        } => {
            assert!(!key.is_empty(), "no key named: {msg}\n{case}");
            assert!(msg.contains(key.as_str()));
            assert!(
                !problem.trim().is_empty(),
                "no problem stated: {msg}\n{case}"
            );
            assert!(fix.trim().len() >= 8, "no fix stated: {msg}\n{case}");
        }
        SceneError::Syntax { line, column, .. } => {
            assert!(*line >= 1 && *column >= 1, "{msg}");
        }
        SceneError::Read { .. } => panic!("no file is read here: {msg}"),
    }
}

#[test]
fn mutated_scenes_never_panic_and_errors_name_file_and_key() {
    let cases: usize = std::env::var("MPM_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000);
    let seed: u64 = std::env::var("MPM_FUZZ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1);
    let corpus = shipped();
    let dir = scenes_dir();
    let mut rng = Rng(seed);
    let (mut accepted, mut refused_key, mut refused_syntax) = (0, 0, 0);
    for n in 0..cases {
        let (name, text) = rng.pick(&corpus).clone();
        let mut doc: Value = Value::Table(text.parse::<Table>().unwrap());
        let text = if rng.below(4) == 0 {
            mutate_text(&mut rng, &text)
        } else {
            for _ in 0..=rng.below(3) {
                mutate_value(&mut rng, &mut doc);
            }
            match &doc {
                Value::Table(t) => toml::to_string(t).unwrap_or_default(),
                _ => unreachable!(),
            }
        };
        let origin = format!("fuzz/{name}");
        let case = format!("case {n} (seed {seed}) from {name}:\n{text}");
        let t0 = std::time::Instant::now();
        let result = std::panic::catch_unwind(AssertUnwindSafe(|| {
            parse_scene_in(&text, &origin, &[], Some(&dir))
        }));
        if t0.elapsed().as_secs_f64() > 0.5 {
            eprintln!("SLOW {:?} {case}", t0.elapsed());
        }
        match result {
            Err(_) => panic!("the parser panicked on {case}"),
            Ok(Ok(scene)) => {
                accepted += 1;
                // An accepted scene has a finite, positive memory estimate.
                let m = scene.memory_estimate();
                assert!(m.total_bytes().is_finite() && m.particles > 0.0, "{case}");
            }
            Ok(Err(e)) => {
                check_error(&e, &origin, &case);
                match e {
                    SceneError::Syntax { .. } => refused_syntax += 1,
                    _ => refused_key += 1,
                }
            }
        }
    }
    // The mutations must exercise both paths, not only one kind of error.
    assert!(accepted > cases / 50, "{accepted} accepted of {cases}");
    assert!(
        refused_key > cases / 3,
        "{refused_key} key errors of {cases}"
    );
    assert!(
        refused_syntax > cases / 50,
        "{refused_syntax} syntax errors of {cases}"
    );
    println!("{cases} cases: {accepted} accepted, {refused_key} key errors, {refused_syntax} syntax errors");
}
