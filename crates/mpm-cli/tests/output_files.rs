//! Output writers (`mpm_cli::output`): PLY and VTU frames, the `.pvd` collection,
//! atomic writes and stats.csv rows.

use mpm_cli::output::{
    ply_bytes, pvd_text, read_ply_positions, vtu_bytes, write_atomic, ParticleFields, StatsRow,
    StatsWriter, VTU_FIELDS,
};
use mpm_math::Real;
use std::path::PathBuf;

fn tmp_dir(tag: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mpm-cli-output-{tag}-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn cloud<T: Real>(n: usize) -> (Vec<[T; 3]>, Vec<[T; 3]>, Vec<u16>) {
    let p = (0..n)
        .map(|i| {
            let x = i as f64;
            [T::lit(0.1 * x), T::lit(-1.0 / (x + 3.0)), T::lit(1e-7 * x)]
        })
        .collect();
    let v = (0..n).map(|i| [T::lit(i as f64); 3]).collect();
    let m = (0..n).map(|i| (i % 3) as u16).collect();
    (p, v, m)
}

fn round_trip<T: Real>(ty: &str) {
    let (p, v, m) = cloud::<T>(101);
    let bytes = ply_bytes(&p, &v, &m);
    let header_len = bytes
        .windows(11)
        .position(|w| w == b"end_header\n")
        .unwrap()
        + 11;
    let text = String::from_utf8_lossy(&bytes[..header_len]);
    assert!(text.starts_with("ply\nformat binary_little_endian 1.0\n"));
    assert!(text.contains(&format!("comment mpm precision {}\n", T::NAME)));
    assert!(text.contains("element vertex 101\n"));
    assert!(text.contains(&format!("property {ty} x\n")));
    assert!(text.contains(&format!("property {ty} vz\n")));
    assert!(text.contains("property ushort material\nend_header\n"));
    let back = read_ply_positions(&bytes).unwrap();
    assert_eq!(back.len(), p.len());
    for (a, b) in back.iter().zip(&p) {
        assert_eq!(*a, [b[0].to_f64(), b[1].to_f64(), b[2].to_f64()]);
    }
    // Size: header + n * (6 scalars + ushort).
    let scalar = if ty == "float" { 4 } else { 8 };
    assert_eq!(bytes.len(), header_len + 101 * (6 * scalar + 2));
    // The material id of the last vertex sits in the last two bytes.
    assert_eq!(&bytes[bytes.len() - 2..], &(100u16 % 3).to_le_bytes());
}

#[test]
fn ply_round_trip_f32() {
    round_trip::<f32>("float");
}

#[test]
fn ply_round_trip_f64() {
    round_trip::<f64>("double");
}

#[test]
fn ply_empty_cloud_and_bad_input() {
    let bytes = ply_bytes::<f64>(&[], &[], &[]);
    assert!(read_ply_positions(&bytes).unwrap().is_empty());
    assert!(read_ply_positions(b"not a ply").is_err());
    let (p, v, m) = cloud::<f64>(5);
    let bytes = ply_bytes(&p, &v, &m);
    assert!(read_ply_positions(&bytes[..bytes.len() - 1]).is_err());
}

fn fields<T: Real>(n: usize, plastic: bool) -> ParticleFields<T> {
    let (p, v, m) = cloud::<T>(n);
    ParticleFields {
        positions: p,
        velocities: v,
        material: m,
        body: (0..n).map(|i| (i % 2) as u16).collect(),
        jacobian: (0..n).map(|i| T::lit(1.0 - 0.01 * i as f64)).collect(),
        stress_norm: (0..n).map(|i| T::lit(1e3 * i as f64)).collect(),
        plastic: plastic.then(|| (0..n).map(|i| T::lit(0.5 * i as f64)).collect()),
    }
}

/// Parses VTU bytes with vtkio; returns the piece.
pub(crate) fn parse_vtu(bytes: &[u8]) -> vtkio::model::UnstructuredGridPiece {
    use vtkio::model::DataSet;
    let vtk = vtkio::Vtk::parse_xml(bytes).unwrap();
    let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
        panic!("not an UnstructuredGrid");
    };
    assert_eq!(pieces.len(), 1);
    pieces[0].load_piece_data(None).unwrap()
}

/// The point-data arrays of a piece by name: (components, values as f64, buffer).
pub(crate) fn vtu_arrays(
    piece: &vtkio::model::UnstructuredGridPiece,
) -> Vec<(String, usize, Vec<f64>, vtkio::IOBuffer)> {
    use vtkio::model::Attribute;
    piece
        .data
        .point
        .iter()
        .map(|a| match a {
            Attribute::DataArray(d) => (
                d.name.clone(),
                d.num_comp(),
                d.data.cast_into::<f64>().unwrap(),
                d.data.clone(),
            ),
            Attribute::Field { name, .. } => panic!("field attribute {name}"),
        })
        .collect()
}

fn vtu_round_trip<T: Real>(plastic: bool) {
    use vtkio::model::{CellType, VertexNumbers};
    let n = 23;
    let f = fields::<T>(n, plastic);
    let bytes = vtu_bytes(&f).unwrap();
    let text = String::from_utf8_lossy(&bytes);
    assert!(
        text.starts_with("<VTKFile type=\"UnstructuredGrid\""),
        "{text:.200}"
    );
    assert!(text.contains("byte_order=\"LittleEndian\""));
    let piece = parse_vtu(&bytes);
    assert_eq!(piece.num_points(), n);
    let single = T::NAME == "f32";
    assert_eq!(
        matches!(piece.points, vtkio::IOBuffer::F32(_)),
        single,
        "points keep the run's precision"
    );
    let pts = piece.points.cast_into::<f64>().unwrap();
    for i in 0..n {
        for a in 0..3 {
            assert_eq!(pts[3 * i + a], f.positions[i][a].to_f64());
        }
    }
    assert_eq!(piece.cells.types, vec![CellType::Vertex; n]);
    match &piece.cells.cell_verts {
        VertexNumbers::XML {
            connectivity,
            offsets,
        } => {
            assert_eq!(connectivity, &(0..n as u64).collect::<Vec<_>>());
            assert_eq!(offsets, &(1..=n as u64).collect::<Vec<_>>());
        }
        other => panic!("{other:?}"),
    }
    let arrays = vtu_arrays(&piece);
    let names: Vec<&str> = arrays.iter().map(|a| a.0.as_str()).collect();
    let expect = if plastic {
        &VTU_FIELDS[..]
    } else {
        &VTU_FIELDS[..5]
    };
    assert_eq!(names, expect);
    for (name, comps, values, buf) in &arrays {
        let want: Vec<f64> = match name.as_str() {
            "velocity" => f
                .velocities
                .iter()
                .flat_map(|v| v.map(|x| x.to_f64()))
                .collect(),
            "material" => f.material.iter().map(|&m| m as f64).collect(),
            "body" => f.body.iter().map(|&m| m as f64).collect(),
            "J" => f.jacobian.iter().map(|x| x.to_f64()).collect(),
            "stress_norm" => f.stress_norm.iter().map(|x| x.to_f64()).collect(),
            "plastic" => f.plastic.iter().flatten().map(|x| x.to_f64()).collect(),
            other => panic!("unexpected array {other}"),
        };
        assert_eq!(*comps, if name == "velocity" { 3 } else { 1 }, "{name}");
        assert_eq!(values, &want, "{name}");
        if name == "material" || name == "body" {
            assert!(matches!(buf, vtkio::IOBuffer::U16(_)), "{name}");
        }
    }
}

#[test]
fn vtu_round_trip_f32_and_f64() {
    vtu_round_trip::<f32>(false);
    vtu_round_trip::<f64>(true);
    vtu_round_trip::<f32>(true);
    // No particles is still a valid file.
    let piece = parse_vtu(&vtu_bytes(&fields::<f64>(0, false)).unwrap());
    assert_eq!(piece.num_points(), 0);
}

#[test]
fn pvd_lists_frames_with_times() {
    let frames = vec![
        (0.0, "frames/frame_00000.vtu".to_string()),
        (0.02, "frames/frame_00001.vtu".to_string()),
        (1.0 / 3.0, "frames/a&b.vtu".to_string()),
    ];
    let text = pvd_text(&frames);
    assert!(text.contains("<VTKFile type=\"Collection\""));
    let entries: Vec<&str> = text.lines().filter(|l| l.contains("<DataSet")).collect();
    assert_eq!(entries.len(), 3);
    assert!(entries[1].contains("timestep=\"2e-2\"") && entries[1].contains("frame_00001.vtu"));
    assert!(entries[2].contains("a&amp;b.vtu"));
    let t: f64 = entries[2]
        .split("timestep=\"")
        .nth(1)
        .and_then(|r| r.split('"').next())
        .unwrap()
        .parse()
        .unwrap();
    assert_eq!(t, 1.0 / 3.0);
}

#[test]
fn write_atomic_replaces_and_leaves_no_tmp() {
    let d = tmp_dir("atomic");
    let path = d.join("frame_00000.ply");
    write_atomic(&path, b"first").unwrap();
    write_atomic(&path, b"second").unwrap();
    assert_eq!(std::fs::read(&path).unwrap(), b"second");
    assert!(!d.join("frame_00000.ply.tmp").exists());
    let names: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(names.len(), 1, "{names:?}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn stats_header_and_rows() {
    let w = StatsWriter::new(vec![]);
    assert_eq!(
        w.header(),
        "frame,time,steps,wall_seconds,particles,mass,kinetic_energy,elastic_energy,\
momentum_x,momentum_y,momentum_z,angular_momentum_x,angular_momentum_y,angular_momentum_z,\
max_speed,reference_updates,potential_energy,newton_iterations,cg_iterations"
    );
    let mut w = StatsWriter::new(vec!["tip_y".into(), "left".into()]);
    assert!(w
        .header()
        .ends_with(",potential_energy,newton_iterations,cg_iterations,tip_y,left"));
    let r = StatsRow {
        frame: 3,
        time: 0.06,
        steps: 120,
        wall_seconds: 1.5,
        particles: 1000,
        mass: 0.1 + 0.2,
        kinetic_energy: 1.0 / 3.0,
        elastic_energy: 0.0,
        momentum: [1e-300, -2.5, 0.0],
        angular_momentum: [0.0, 0.0, 7.0],
        max_speed: 12.25,
        reference_updates: 0,
        potential_energy: -2.0,
        newton_iterations: 4,
        cg_iterations: 310,
    };
    let row = w.row(&r, &[0.25, -1.0]);
    let fields: Vec<&str> = row.split(',').collect();
    assert_eq!(fields.len(), 19 + 2);
    assert_eq!((fields[17], fields[18]), ("4", "310"));
    assert_eq!(fields.len(), w.header().split(',').count());
    // Floats round-trip exactly.
    assert_eq!(fields[0], "3");
    assert_eq!(fields[5].parse::<f64>().unwrap(), 0.1 + 0.2);
    assert_eq!(fields[6].parse::<f64>().unwrap(), 1.0 / 3.0);
    assert_eq!(fields[8].parse::<f64>().unwrap(), 1e-300);
    assert_eq!(fields[15], "0");
    w.push(&r, &[0.25, -1.0]);
    w.push(&r, &[0.5, -1.0]);
    assert_eq!(w.contents().lines().count(), 3);
    let d = tmp_dir("stats");
    let path = d.join("stats.csv");
    w.write(&path).unwrap();
    assert_eq!(std::fs::read_to_string(&path).unwrap(), w.contents());
    std::fs::remove_dir_all(&d).unwrap();
}
