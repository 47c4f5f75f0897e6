//! Output files: atomic writes, binary PLY frames, VTU frames with their `.pvd`
//! collection, and stats.csv rows.

use std::io::Write;
use std::path::{Path, PathBuf};

use mpm_math::Real;

/// Writes `bytes` to `path` + ".tmp" in the same directory, syncs it and renames it
/// over `path`, so an interrupted run never leaves a half-written file under `path`.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = tmp_path(path);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        // Best effort: do not leave a stray temporary behind.
        let _ = std::fs::remove_file(&tmp);
    }
    result
}

fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.as_os_str().to_owned();
    name.push(".tmp");
    PathBuf::from(name)
}

/// A binary little-endian PLY point cloud: `x y z vx vy vz` as `float` (f32) or
/// `double` (f64), then `ushort material`.
///
/// Written by hand rather than with a PLY crate: those build a property map per
/// vertex, which is slow and memory-hungry for millions of particles every frame;
/// here it is one header and a flat byte buffer.
///
/// Panics if the three slices differ in length (a caller bug, not user input).
pub fn ply_bytes<T: Real>(
    positions: &[[T; 3]],
    velocities: &[[T; 3]],
    material: &[u16],
) -> Vec<u8> {
    let n = positions.len();
    assert_eq!(velocities.len(), n, "one velocity per position");
    assert_eq!(material.len(), n, "one material id per position");
    let single = T::NAME == "f32";
    let ty = if single { "float" } else { "double" };
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment mpm precision {}\nelement vertex {n}\n",
        T::NAME
    );
    for p in ["x", "y", "z", "vx", "vy", "vz"] {
        header.push_str(&format!("property {ty} {p}\n"));
    }
    header.push_str("property ushort material\nend_header\n");

    let scalar = if single { 4 } else { 8 };
    let mut out = Vec::with_capacity(header.len() + n * (6 * scalar + 2));
    out.extend_from_slice(header.as_bytes());
    for i in 0..n {
        for x in positions[i].iter().chain(velocities[i].iter()) {
            // to_f64 is exact, and narrowing an f32's widened value back is exact too.
            let x = x.to_f64();
            if single {
                out.extend_from_slice(&(x as f32).to_le_bytes());
            } else {
                out.extend_from_slice(&x.to_le_bytes());
            }
        }
        out.extend_from_slice(&material[i].to_le_bytes());
    }
    out
}

/// Reads the positions back from a binary little-endian PLY with `x`, `y`, `z`
/// properties of type float or double (other scalar properties are skipped).
pub fn read_ply_positions(bytes: &[u8]) -> Result<Vec<[f64; 3]>, String> {
    let cols = read_ply_columns(bytes, &["x", "y", "z"])?;
    Ok((0..cols[0].len())
        .map(|i| [cols[0][i], cols[1][i], cols[2][i]])
        .collect())
}

/// One point-data array of a VTU file (as written by `mpm run`), by name, as `f64`;
/// vector arrays (velocity) become their magnitude per point.
pub fn read_vtu_field(bytes: &[u8], name: &str) -> Result<Vec<f64>, String> {
    use vtkio::model::{Attribute, DataSet};
    let vtk = vtkio::Vtk::parse_xml(bytes).map_err(|e| format!("not a readable VTU file ({e})"))?;
    let DataSet::UnstructuredGrid { pieces, .. } = vtk.data else {
        return Err("not an UnstructuredGrid".into());
    };
    let piece = pieces
        .into_iter()
        .next()
        .ok_or("no piece")?
        .load_piece_data(None)
        .map_err(|e| format!("cannot load the piece ({e})"))?;
    let mut names = Vec::new();
    for a in &piece.data.point {
        if let Attribute::DataArray(d) = a {
            if d.name == name {
                let comp = d.num_comp().max(1);
                let values: Vec<f64> = d
                    .data
                    .clone()
                    .cast_into::<f64>()
                    .ok_or_else(|| format!("array {name} is not numeric"))?;
                if comp == 1 {
                    return Ok(values);
                }
                return Ok(values
                    .chunks(comp)
                    .map(|c| c.iter().map(|x| x * x).sum::<f64>().sqrt())
                    .collect());
            }
            names.push(d.name.clone());
        }
    }
    Err(format!(
        "no point array `{name}`; it has {}",
        names.join(", ")
    ))
}

/// Reads the named scalar vertex properties (any PLY numeric type, widened to
/// `f64`) of a binary little-endian PLY, one column per name, in the order asked.
pub fn read_ply_columns(bytes: &[u8], names: &[&str]) -> Result<Vec<Vec<f64>>, String> {
    const END: &[u8] = b"end_header\n";
    let end = bytes
        .windows(END.len())
        .position(|w| w == END)
        .ok_or("no end_header line")?
        + END.len();
    let header =
        std::str::from_utf8(&bytes[..end]).map_err(|e| format!("header is not UTF-8: {e}"))?;
    let mut lines = header.lines();
    if lines.next() != Some("ply") {
        return Err("not a PLY file (first line is not `ply`)".into());
    }
    let mut count: Option<usize> = None;
    let mut in_vertex = false;
    // (size in bytes, type, name) of each vertex property, in order.
    let mut props: Vec<(usize, &str, &str)> = Vec::new();
    for line in lines {
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", fmt, _] if *fmt != "binary_little_endian" => {
                return Err(format!("unsupported format `{fmt}`"));
            }
            ["element", "vertex", n] => {
                count = Some(n.parse().map_err(|e| format!("bad vertex count: {e}"))?);
                in_vertex = true;
            }
            ["element", ..] => {
                if count.is_some() {
                    // Only the vertex element is read; it must come first.
                    in_vertex = false;
                } else {
                    return Err("elements before `vertex` are not supported".into());
                }
            }
            ["property", "list", ..] if in_vertex => {
                return Err("list properties on vertices are not supported".into());
            }
            ["property", ty, name] if in_vertex => {
                let size = match *ty {
                    "char" | "uchar" | "int8" | "uint8" => 1,
                    "short" | "ushort" | "int16" | "uint16" => 2,
                    "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
                    "double" | "float64" => 8,
                    other => return Err(format!("unknown property type `{other}`")),
                };
                props.push((size, ty, name));
            }
            _ => {}
        }
    }
    let n = count.ok_or("no `element vertex` line")?;
    let stride: usize = props.iter().map(|p| p.0).sum();
    let mut wanted = Vec::with_capacity(names.len());
    for name in names {
        let mut off = 0;
        let mut found = None;
        for (size, ty, pname) in &props {
            if pname == name {
                found = Some((off, *ty));
                break;
            }
            off += size;
        }
        wanted.push(found.ok_or_else(|| format!("no vertex property `{name}`"))?);
    }
    let body = &bytes[end..];
    if body.len() < n * stride {
        return Err(format!(
            "truncated: {n} vertices need {} bytes, found {}",
            n * stride,
            body.len()
        ));
    }
    let mut out = vec![Vec::with_capacity(n); names.len()];
    for v in 0..n {
        let rec = &body[v * stride..(v + 1) * stride];
        for (col, &(o, ty)) in out.iter_mut().zip(&wanted) {
            let b4 = || [rec[o], rec[o + 1], rec[o + 2], rec[o + 3]];
            let b2 = || [rec[o], rec[o + 1]];
            let x = match ty {
                "double" | "float64" => {
                    let mut a = [0u8; 8];
                    a.copy_from_slice(&rec[o..o + 8]);
                    f64::from_le_bytes(a)
                }
                "float" | "float32" => f32::from_le_bytes(b4()) as f64,
                "char" | "int8" => rec[o] as i8 as f64,
                "uchar" | "uint8" => rec[o] as f64,
                "short" | "int16" => i16::from_le_bytes(b2()) as f64,
                "ushort" | "uint16" => u16::from_le_bytes(b2()) as f64,
                "int" | "int32" => i32::from_le_bytes(b4()) as f64,
                _ => u32::from_le_bytes(b4()) as f64,
            };
            col.push(x);
        }
    }
    Ok(out)
}

/// Per-particle fields of one VTU frame, in particle creation order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ParticleFields<T> {
    /// Positions (2-D: z = 0).
    pub positions: Vec<[T; 3]>,
    /// Velocities (2-D: z = 0).
    pub velocities: Vec<[T; 3]>,
    /// Index into the scene's materials.
    pub material: Vec<u16>,
    /// Index into the scene's bodies.
    pub body: Vec<u16>,
    /// Volume ratio: `det F` (`det F_E` for the plastic models), or the fluid's `J`.
    pub jacobian: Vec<T>,
    /// Frobenius norm of the Kirchhoff stress `‖τ‖_F` (Pa).
    pub stress_norm: Vec<T>,
    /// The plastic models' hardening scalar, when the scene has one (0 for particles of
    /// the other models).
    pub plastic: Option<Vec<T>>,
}

/// Names of the VTU point-data arrays, in file order (`plastic` only when present).
pub const VTU_FIELDS: [&str; 6] = [
    "velocity",
    "material",
    "body",
    "J",
    "stress_norm",
    "plastic",
];

fn io_buffer<T: Real>(values: impl Iterator<Item = T>) -> vtkio::IOBuffer {
    // The file keeps the run's precision.
    if T::NAME == "f32" {
        vtkio::IOBuffer::F32(values.map(|x| x.to_f64() as f32).collect())
    } else {
        vtkio::IOBuffer::F64(values.map(|x| x.to_f64()).collect())
    }
}

/// A VTK XML UnstructuredGrid (`.vtu`, base64 binary arrays, little-endian) with one
/// `VTK_VERTEX` cell per particle and the fields as point data, written by vtkio.
///
/// Panics if the field arrays differ in length (a caller bug, not user input).
pub fn vtu_bytes<T: Real>(f: &ParticleFields<T>) -> Result<Vec<u8>, vtkio::Error> {
    use vtkio::model::{
        Attribute, Attributes, ByteOrder, CellType, Cells, DataSet, UnstructuredGridPiece, Version,
        VertexNumbers, Vtk,
    };
    let n = f.positions.len();
    for len in [
        f.velocities.len(),
        f.material.len(),
        f.body.len(),
        f.jacobian.len(),
        f.stress_norm.len(),
    ] {
        assert_eq!(len, n, "one value per particle");
    }
    let flat = |v: &[[T; 3]]| io_buffer(v.iter().flat_map(|p| p.iter().copied()));
    let mut point = vec![
        Attribute::vectors(VTU_FIELDS[0]).with_data(flat(&f.velocities)),
        Attribute::scalars(VTU_FIELDS[1], 1).with_data(f.material.clone()),
        Attribute::scalars(VTU_FIELDS[2], 1).with_data(f.body.clone()),
        Attribute::scalars(VTU_FIELDS[3], 1).with_data(io_buffer(f.jacobian.iter().copied())),
        Attribute::scalars(VTU_FIELDS[4], 1).with_data(io_buffer(f.stress_norm.iter().copied())),
    ];
    if let Some(q) = &f.plastic {
        assert_eq!(q.len(), n, "one value per particle");
        point.push(Attribute::scalars(VTU_FIELDS[5], 1).with_data(io_buffer(q.iter().copied())));
    }
    let vtk = Vtk {
        version: Version::new_xml(1, 0),
        title: String::new(),
        byte_order: ByteOrder::LittleEndian,
        file_path: None,
        data: DataSet::inline(UnstructuredGridPiece {
            points: flat(&f.positions),
            cells: Cells {
                cell_verts: VertexNumbers::XML {
                    connectivity: (0..n as u64).collect(),
                    offsets: (1..=n as u64).collect(),
                },
                types: vec![CellType::Vertex; n],
            },
            data: Attributes {
                point,
                cell: Vec::new(),
            },
        }),
    };
    let mut out = Vec::new();
    vtk.write_xml(&mut out)?;
    Ok(out)
}

/// A ParaView collection (`.pvd`) listing `(time, file)` pairs, files relative to the
/// collection's directory. Written by hand: vtkio has no collection type, and this is
/// a few lines of plain XML.
pub fn pvd_text(frames: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n",
    );
    for (time, file) in frames {
        let file = file
            .replace('&', "&amp;")
            .replace('"', "&quot;")
            .replace('<', "&lt;");
        s.push_str(&format!(
            "    <DataSet timestep=\"{time:e}\" group=\"\" part=\"0\" file=\"{file}\"/>\n"
        ));
    }
    s.push_str("  </Collection>\n</VTKFile>\n");
    s
}

/// One stats.csv row's standard columns (SI units, totals over all particles).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StatsRow {
    pub frame: usize,
    pub time: f64,
    pub steps: u64,
    pub wall_seconds: f64,
    pub particles: usize,
    pub mass: f64,
    pub kinetic_energy: f64,
    pub elastic_energy: f64,
    pub momentum: [f64; 3],
    pub angular_momentum: [f64; 3],
    pub max_speed: f64,
    pub reference_updates: u64,
    /// Gravitational potential energy `−Σ m g·x` (so that kinetic + elastic +
    /// potential is the total mechanical energy).
    pub potential_energy: f64,
    /// Newton iterations so far (0 for the explicit integrator).
    pub newton_iterations: u64,
    /// Conjugate-gradient iterations so far (0 for the explicit integrator).
    pub cg_iterations: u64,
}

/// Builds stats.csv: the header, then one row per frame. The whole text is kept so the
/// driver can rewrite the file atomically each frame (it is then always complete).
#[derive(Clone, Debug)]
pub struct StatsWriter {
    probes: Vec<String>,
    text: String,
}

/// The standard columns, in order.
pub const STATS_HEADER: &str = "frame,time,steps,wall_seconds,particles,mass,kinetic_energy,\
elastic_energy,momentum_x,momentum_y,momentum_z,angular_momentum_x,angular_momentum_y,\
angular_momentum_z,max_speed,reference_updates,potential_energy,newton_iterations,cg_iterations";

impl StatsWriter {
    /// `probe_names` become extra columns after the standard ones.
    pub fn new(probe_names: Vec<String>) -> Self {
        let mut w = StatsWriter {
            probes: probe_names,
            text: String::new(),
        };
        w.text = w.header();
        w.text.push('\n');
        w
    }

    /// A writer continuing `contents` (a checkpoint's stats.csv), which must start with
    /// this writer's header.
    pub fn from_contents(probe_names: Vec<String>, contents: String) -> Result<Self, String> {
        let w = StatsWriter {
            probes: probe_names,
            text: contents,
        };
        let header = w.header();
        match w.text.lines().next() {
            Some(first) if first == header && w.text.ends_with('\n') => Ok(w),
            _ => Err(format!(
                "its stats.csv rows do not match the scene's columns ({header})"
            )),
        }
    }

    /// The header line (no newline).
    pub fn header(&self) -> String {
        let mut h = STATS_HEADER.to_string();
        for p in &self.probes {
            h.push(',');
            h.push_str(p);
        }
        h
    }

    /// One row (no newline). Floats use `{:e}`: the shortest digits that round-trip.
    ///
    /// Panics if `probe_values` does not have one value per probe (a caller bug).
    pub fn row(&self, r: &StatsRow, probe_values: &[f64]) -> String {
        assert_eq!(probe_values.len(), self.probes.len(), "one value per probe");
        let mut s = format!(
            "{},{:e},{},{:e},{},{:e},{:e},{:e}",
            r.frame,
            r.time,
            r.steps,
            r.wall_seconds,
            r.particles,
            r.mass,
            r.kinetic_energy,
            r.elastic_energy
        );
        for x in r
            .momentum
            .iter()
            .chain(r.angular_momentum.iter())
            .chain([r.max_speed].iter())
        {
            s.push_str(&format!(",{x:e}"));
        }
        s.push_str(&format!(",{}", r.reference_updates));
        s.push_str(&format!(",{:e}", r.potential_energy));
        s.push_str(&format!(",{},{}", r.newton_iterations, r.cg_iterations));
        for x in probe_values {
            s.push_str(&format!(",{x:e}"));
        }
        s
    }

    /// Appends a row to the kept text.
    pub fn push(&mut self, r: &StatsRow, probe_values: &[f64]) {
        let line = self.row(r, probe_values);
        self.text.push_str(&line);
        self.text.push('\n');
    }

    /// The whole file so far: header and every pushed row, newline-terminated.
    pub fn contents(&self) -> &str {
        &self.text
    }

    /// Rewrites `path` atomically with [`StatsWriter::contents`].
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        write_atomic(path, self.text.as_bytes())
    }
}
