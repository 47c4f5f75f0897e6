//! Triangle meshes for `shape = { type = "mesh", … }` bodies: reading OBJ (tobj) and
//! STL (stl_io), the closedness check, the scene transform, the exact enclosed
//! volume, and the inside test by the generalised winding number, accelerated by a
//! bounding-volume tree whose far nodes are replaced by exact boundary fans.
//! Also the generators of the two shipped meshes (`examples/make_meshes.rs`).

use std::collections::HashMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// A triangle mesh: vertex positions and index triples (counter-clockwise seen from
/// outside for an outward-oriented mesh).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TriMesh {
    pub vertices: Vec<[f64; 3]>,
    pub triangles: Vec<[u32; 3]>,
}

/// Why a mesh file cannot be used as a body. The messages do not name the file: the
/// scene error that wraps them does.
#[derive(Debug, thiserror::Error)]
pub enum MeshError {
    #[error("cannot read the mesh file ({0})")]
    Read(#[source] std::io::Error),
    #[error("not a valid OBJ file ({0})")]
    Obj(String),
    #[error("not a valid STL file ({0})")]
    Stl(String),
    #[error("the file name has no .obj or .stl extension (\"{0}\")")]
    Format(String),
    #[error("the mesh has no triangles")]
    Empty,
    #[error("vertex {0} has a non-finite coordinate")]
    NonFinite(usize),
    #[error("{count} boundary edge{} (used by one triangle only; one joins {} and {}): the mesh is not closed", if *.count == 1 { "" } else { "s" }, fmt_point(.example.0), fmt_point(.example.1))]
    Open {
        count: usize,
        example: ([f64; 3], [f64; 3]),
    },
    #[error("{count} edge{} shared by more than two triangles (one joins {} and {}): the mesh is not a manifold surface", if *.count == 1 { "" } else { "s" }, fmt_point(.example.0), fmt_point(.example.1))]
    NonManifold {
        count: usize,
        example: ([f64; 3], [f64; 3]),
    },
    #[error("{count} edge{} used twice in the same direction (one joins {} and {}): the triangles are not consistently oriented", if *.count == 1 { "" } else { "s" }, fmt_point(.example.0), fmt_point(.example.1))]
    Inconsistent {
        count: usize,
        example: ([f64; 3], [f64; 3]),
    },
    #[error("{count} pair{} of triangles cross each other (an edge pierces a triangle at {}): the surface intersects itself, so its inside is ambiguous", if *.count == 1 { "" } else { "s" }, fmt_point(*.at))]
    SelfIntersecting { count: usize, at: [f64; 3] },
}

impl MeshError {
    /// How to fix it, for the scene error's "fix" part.
    pub fn fix(&self) -> &'static str {
        match self {
            MeshError::Read(_) => {
                "Check the path: a relative path is taken from the scene file's directory"
            }
            MeshError::Obj(_) | MeshError::Stl(_) => {
                "Export the mesh again as a triangulated OBJ or an ASCII/binary STL"
            }
            MeshError::Format(_) => "Give a path ending in .obj or .stl",
            MeshError::Empty | MeshError::NonFinite(_) => {
                "Export the mesh again: it needs triangles with finite vertex coordinates"
            }
            MeshError::Open { .. } | MeshError::NonManifold { .. } => {
                "Give a closed (watertight) mesh: every edge must be shared by exactly two \
                 triangles (close the holes, e.g. with a mesh repair tool)"
            }
            MeshError::SelfIntersecting { .. } => {
                "Repair the mesh so its surface does not cross itself (e.g. a boolean union \
                 of the overlapping parts in a mesh tool)"
            }
            MeshError::Inconsistent { .. } => {
                "Orient every triangle the same way (all normals outward), e.g. with a mesh \
                 repair tool's 'unify normals'"
            }
        }
    }
}

fn fmt_point(p: [f64; 3]) -> String {
    format!("({}, {}, {})", p[0], p[1], p[2])
}

/// Reads an OBJ or STL file (by extension, case-insensitive). Coincident vertices
/// are merged (STL stores each triangle's corners separately; OBJ groups may repeat
/// positions) and triangles that repeat a vertex are dropped.
pub fn load(path: &Path) -> Result<TriMesh, MeshError> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let soup: Vec<[[f64; 3]; 3]> = match ext.as_str() {
        "obj" => read_obj(path)?,
        "stl" => read_stl(path)?,
        _ => return Err(MeshError::Format(path.display().to_string())),
    };
    TriMesh::from_soup(&soup)
}

fn read_obj(path: &Path) -> Result<Vec<[[f64; 3]; 3]>, MeshError> {
    let file = std::fs::File::open(path).map_err(MeshError::Read)?;
    let mut reader = std::io::BufReader::new(file);
    let opts = tobj::LoadOptions {
        triangulate: true,
        ignore_points: true,
        ignore_lines: true,
        ..Default::default()
    };
    // Materials do not matter for a body: never open the .mtl files.
    let (models, _) = tobj::load_obj_buf(&mut reader, &opts, |_| Ok(Default::default()))
        .map_err(|e| MeshError::Obj(e.to_string()))?;
    let mut soup = Vec::new();
    for m in &models {
        let pos = &m.mesh.positions;
        for t in m.mesh.indices.chunks(3) {
            let mut tri = [[0.0; 3]; 3];
            for (c, &i) in t.iter().enumerate() {
                let i = i as usize;
                let p = pos
                    .get(3 * i..3 * i + 3)
                    .ok_or_else(|| MeshError::Obj(format!("face index {} out of range", i + 1)))?;
                tri[c] = [p[0] as f64, p[1] as f64, p[2] as f64];
            }
            if t.len() == 3 {
                soup.push(tri);
            }
        }
    }
    Ok(soup)
}

fn read_stl(path: &Path) -> Result<Vec<[[f64; 3]; 3]>, MeshError> {
    let file = std::fs::File::open(path).map_err(MeshError::Read)?;
    let mut reader = std::io::BufReader::new(file);
    let tris = stl_io::create_stl_reader(&mut reader).map_err(|e| MeshError::Stl(e.to_string()))?;
    let mut soup = Vec::new();
    for t in tris {
        let t = t.map_err(|e| MeshError::Stl(e.to_string()))?;
        soup.push(t.vertices.map(|v| v.0.map(f64::from)));
    }
    Ok(soup)
}

/// `a − b`, `a × b`, `a · b`, `|a|` on 3-vectors.
fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Where an edge of one triangle pierces the other's interior, if one does.
fn triangles_cross(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> Option<[f64; 3]> {
    for (tri, other) in [(a, b), (b, a)] {
        for k in 0..3 {
            if let Some(p) = segment_pierces(other[k], other[(k + 1) % 3], tri) {
                return Some(p);
            }
        }
    }
    None
}

/// Möller–Trumbore: the point where segment `p→q` crosses the plane of triangle `t`
/// inside the triangle, edges included (a crossing exactly through an edge is still a
/// crossing: two meshes mirror-symmetric about a plane meet only on edges), with
/// the segment parameter strictly inside (0, 1) by a relative 1e-9, so a vertex that
/// merely rests on the other surface does not count.
fn segment_pierces(p: [f64; 3], q: [f64; 3], t: [[f64; 3]; 3]) -> Option<[f64; 3]> {
    const EPS: f64 = 1e-9;
    let d = sub(q, p);
    let e1 = sub(t[1], t[0]);
    let e2 = sub(t[2], t[0]);
    let h = cross(d, e2);
    let det = dot(e1, h);
    // Parallel (or degenerate): no transversal crossing.
    if det.abs() <= EPS * norm(d) * norm(e1) * norm(e2) {
        return None;
    }
    let inv = 1.0 / det;
    let s = sub(p, t[0]);
    let u = dot(s, h) * inv;
    let qv = cross(s, e1);
    let v = dot(d, qv) * inv;
    let w = dot(e2, qv) * inv;
    let inside = u >= -EPS && v >= -EPS && u + v <= 1.0 + EPS && w > EPS && w < 1.0 - EPS;
    inside.then(|| [p[0] + w * d[0], p[1] + w * d[1], p[2] + w * d[2]])
}

/// Dot product of two 3-vectors (public for the integration tests).
#[doc(hidden)]
pub fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn norm(a: [f64; 3]) -> f64 {
    dot(a, a).sqrt()
}

/// Signed solid angle of triangle `abc` seen from `p`, by van Oosterom & Strackee
/// (1983): `tan(Ω/2) = a·(b×c) / (|a||b||c| + (a·b)|c| + (b·c)|a| + (c·a)|b|)` with
/// `a, b, c` relative to `p`. Positive when `p` is on the side the counter-clockwise
/// normal points away from (inside an outward-oriented closed mesh).
pub fn solid_angle(p: [f64; 3], a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    let (a, b, c) = (sub(a, p), sub(b, p), sub(c, p));
    let (la, lb, lc) = (norm(a), norm(b), norm(c));
    let num = dot(a, cross(b, c));
    let den = la * lb * lc + dot(a, b) * lc + dot(b, c) * la + dot(c, a) * lb;
    2.0 * num.atan2(den)
}

/// The rotation `R = R_z(γ) R_y(β) R_x(α)` for Euler angles `[α, β, γ]` in degrees:
/// about the fixed x axis first, then y, then z.
pub fn rotation_matrix(deg: [f64; 3]) -> [[f64; 3]; 3] {
    let [a, b, g] = deg.map(f64::to_radians);
    let (sa, ca) = a.sin_cos();
    let (sb, cb) = b.sin_cos();
    let (sg, cg) = g.sin_cos();
    let rx = [[1.0, 0.0, 0.0], [0.0, ca, -sa], [0.0, sa, ca]];
    let ry = [[cb, 0.0, sb], [0.0, 1.0, 0.0], [-sb, 0.0, cb]];
    let rz = [[cg, -sg, 0.0], [sg, cg, 0.0], [0.0, 0.0, 1.0]];
    matmul(rz, matmul(ry, rx))
}

fn matmul(a: [[f64; 3]; 3], b: [[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut c = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            c[i][j] = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    c
}

/// Undirected edge key and the direction it was walked in (+1 from low to high index).
fn edge_key(a: u32, b: u32) -> ((u32, u32), i32) {
    if a < b {
        ((a, b), 1)
    } else {
        ((b, a), -1)
    }
}

impl TriMesh {
    /// A mesh from a triangle soup: bit-identical positions become one vertex
    /// (`-0.0` and `0.0` too); triangles with a repeated vertex are dropped.
    pub fn from_soup(soup: &[[[f64; 3]; 3]]) -> Result<TriMesh, MeshError> {
        let mut index: HashMap<[u64; 3], u32> = HashMap::new();
        let mut mesh = TriMesh::default();
        for tri in soup {
            let mut t = [0u32; 3];
            for (c, p) in tri.iter().enumerate() {
                if p.iter().any(|x| !x.is_finite()) {
                    return Err(MeshError::NonFinite(mesh.vertices.len()));
                }
                let key = p.map(|x| (x + 0.0).to_bits());
                let next = mesh.vertices.len() as u32;
                t[c] = *index.entry(key).or_insert_with(|| {
                    mesh.vertices.push(*p);
                    next
                });
            }
            if t[0] != t[1] && t[1] != t[2] && t[2] != t[0] {
                mesh.triangles.push(t);
            }
        }
        if mesh.triangles.is_empty() {
            return Err(MeshError::Empty);
        }
        Ok(mesh)
    }

    /// Checks that the mesh bounds a solid: every undirected edge is used by exactly
    /// two triangles, walked in opposite directions (a closed, consistently oriented
    /// 2-manifold-with-pinches). Self-intersections: [`Self::check_self_intersection`].
    pub fn check_closed(&self) -> Result<(), MeshError> {
        if self.triangles.is_empty() {
            return Err(MeshError::Empty);
        }
        // (uses, sum of directions) per undirected edge.
        let mut edges: HashMap<(u32, u32), (u32, i32)> = HashMap::new();
        for t in &self.triangles {
            for c in 0..3 {
                let (k, d) = edge_key(t[c], t[(c + 1) % 3]);
                let e = edges.entry(k).or_insert((0, 0));
                e.0 += 1;
                e.1 += d;
            }
        }
        // The lowest offending edge is the example, so messages are reproducible.
        let worst = |pred: &dyn Fn(u32, i32) -> bool| {
            let bad: Vec<(u32, u32)> = edges
                .iter()
                .filter(|(_, &(n, d))| pred(n, d))
                .map(|(k, _)| *k)
                .collect();
            bad.iter().min().map(|&(a, b)| {
                (
                    bad.len(),
                    (self.vertices[a as usize], self.vertices[b as usize]),
                )
            })
        };
        if let Some((count, example)) = worst(&|n, _| n == 1) {
            return Err(MeshError::Open { count, example });
        }
        if let Some((count, example)) = worst(&|n, _| n > 2) {
            return Err(MeshError::NonManifold { count, example });
        }
        if let Some((count, example)) = worst(&|_, d| d != 0) {
            return Err(MeshError::Inconsistent { count, example });
        }
        Ok(())
    }

    /// Checks that no two triangles without a common vertex cross: an edge of one
    /// piercing the interior of the other (Möller–Trumbore with the segment parameter
    /// in (0, 1)). Candidate pairs come from a uniform hash grid of triangle bounding
    /// boxes (cell = mean edge length), so the cost is about linear in the triangles.
    /// Touching at a point and coplanar overlaps are not reported; triangles sharing a
    /// vertex are skipped (adjacent triangles meet by design).
    pub fn check_self_intersection(&self) -> Result<(), MeshError> {
        let n = self.triangles.len();
        if n < 4 {
            return Ok(());
        }
        let boxes: Vec<([f64; 3], [f64; 3])> = self
            .triangles
            .iter()
            .map(|t| {
                let c = self.corners(t);
                let mut lo = c[0];
                let mut hi = c[0];
                for p in &c[1..] {
                    for a in 0..3 {
                        lo[a] = lo[a].min(p[a]);
                        hi[a] = hi[a].max(p[a]);
                    }
                }
                (lo, hi)
            })
            .collect();
        let mean_edge = self
            .triangles
            .iter()
            .map(|t| {
                let c = self.corners(t);
                (0..3).map(|k| norm(sub(c[(k + 1) % 3], c[k]))).sum::<f64>() / 3.0
            })
            .sum::<f64>()
            / n as f64;
        let cell = mean_edge.max(f64::MIN_POSITIVE);
        let key = |p: f64| (p / cell).floor() as i64;
        let mut grid: HashMap<[i64; 3], Vec<u32>> = HashMap::new();
        for (i, (lo, hi)) in boxes.iter().enumerate() {
            let (k0, k1) = (lo.map(key), hi.map(key));
            // A triangle much larger than the cells is put in every cell it spans; cap
            // the span so one huge triangle cannot blow up the table.
            let span: i64 = (0..3).map(|a| k1[a] - k0[a] + 1).product();
            if span > 4096 {
                grid.entry([i64::MIN; 3]).or_default().push(i as u32);
                continue;
            }
            for x in k0[0]..=k1[0] {
                for y in k0[1]..=k1[1] {
                    for z in k0[2]..=k1[2] {
                        grid.entry([x, y, z]).or_default().push(i as u32);
                    }
                }
            }
        }
        let big: Vec<u32> = grid.get(&[i64::MIN; 3]).cloned().unwrap_or_default();
        let overlap = |a: usize, b: usize| {
            (0..3).all(|k| boxes[a].0[k] <= boxes[b].1[k] && boxes[b].0[k] <= boxes[a].1[k])
        };
        let mut seen: std::collections::HashSet<(u32, u32)> = std::collections::HashSet::new();
        let mut count = 0usize;
        let mut first: Option<(u32, u32, [f64; 3])> = None;
        let mut test = |a: u32, b: u32| {
            let (a, b) = (a.min(b), a.max(b));
            if a == b || !overlap(a as usize, b as usize) || !seen.insert((a, b)) {
                return;
            }
            let (ta, tb) = (self.triangles[a as usize], self.triangles[b as usize]);
            if ta.iter().any(|v| tb.contains(v)) {
                return;
            }
            if let Some(at) = triangles_cross(self.corners(&ta), self.corners(&tb)) {
                count += 1;
                if first.is_none_or(|(fa, fb, _)| (a, b) < (fa, fb)) {
                    first = Some((a, b, at));
                }
            }
        };
        for (k, list) in &grid {
            if *k == [i64::MIN; 3] {
                continue;
            }
            for (i, &a) in list.iter().enumerate() {
                for &b in &list[i + 1..] {
                    test(a, b);
                }
                for &b in &big {
                    test(a, b);
                }
            }
        }
        for (i, &a) in big.iter().enumerate() {
            for &b in &big[i + 1..] {
                test(a, b);
            }
        }
        match first {
            Some((_, _, at)) => Err(MeshError::SelfIntersecting { count, at }),
            None => Ok(()),
        }
    }

    /// `x ↦ R (s x) + t` applied to every vertex ([`rotation_matrix`] for `R`).
    pub fn transformed(&self, scale: f64, rotate_deg: [f64; 3], translate: [f64; 3]) -> TriMesh {
        let r = rotation_matrix(rotate_deg);
        let vertices = self
            .vertices
            .iter()
            .map(|p| {
                let mut q = [0.0; 3];
                for i in 0..3 {
                    q[i] = scale * dot(r[i], *p) + translate[i];
                }
                q
            })
            .collect();
        TriMesh {
            vertices,
            triangles: self.triangles.clone(),
        }
    }

    fn corners(&self, t: &[u32; 3]) -> [[f64; 3]; 3] {
        t.map(|i| self.vertices[i as usize])
    }

    /// Enclosed volume by the divergence theorem, `V = Σ a·(b×c) / 6` over triangles
    /// (positive for an outward-oriented closed mesh, negative if inside-out).
    pub fn signed_volume(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                dot(a, cross(b, c)) / 6.0
            })
            .sum()
    }

    /// Surface area `Σ |(b−a)×(c−a)| / 2`.
    pub fn area(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                0.5 * norm(cross(sub(b, a), sub(c, a)))
            })
            .sum()
    }

    /// Axis-aligned bounding box of the vertices used by triangles.
    pub fn bounds(&self) -> ([f64; 3], [f64; 3]) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for t in &self.triangles {
            for p in self.corners(t) {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
        }
        (lo, hi)
    }

    /// The winding number at `p` by the direct sum over all triangles,
    /// `w = Σ Ω / 4π` (the reference for [`SolidMesh::winding_number`]).
    pub fn winding_number_direct(&self, p: [f64; 3]) -> f64 {
        let s: f64 = self
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                solid_angle(p, a, b, c)
            })
            .sum();
        s / (4.0 * PI)
    }

    /// Wavefront OBJ text (1-based indices, shortest round-trip decimals).
    pub fn to_obj(&self, comment: &str) -> String {
        let mut s = String::new();
        for line in comment.lines() {
            s.push_str(&format!("# {line}\n"));
        }
        for v in &self.vertices {
            s.push_str(&format!("v {} {} {}\n", v[0], v[1], v[2]));
        }
        for t in &self.triangles {
            s.push_str(&format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1));
        }
        s
    }

    /// Binary STL bytes (single precision, as the format stores).
    pub fn to_stl(&self) -> std::io::Result<Vec<u8>> {
        let tris: Vec<stl_io::Triangle> = self
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = self.corners(t);
                let n = cross(sub(b, a), sub(c, a));
                let l = norm(n).max(f64::MIN_POSITIVE);
                stl_io::Triangle {
                    normal: stl_io::Normal::new(n.map(|x| (x / l) as f32)),
                    vertices: [a, b, c].map(|p| stl_io::Vertex::new(p.map(|x| x as f32))),
                }
            })
            .collect();
        let mut out = Vec::new();
        stl_io::write_stl(&mut out, tris.iter())?;
        Ok(out)
    }
}

/// The loaded, transformed and checked mesh of a `mesh` shape, kept with the file and
/// transform it came from so that an edited shape is loaded again. Not a scene key:
/// clones get their own copy, and it never makes two shapes unequal.
#[derive(Default)]
pub struct MeshCache(Mutex<Option<(MeshKey, Arc<SolidMesh>)>>);

/// File and transform (as bits) a cached mesh was made from.
type MeshKey = (PathBuf, u64, [u64; 3], [u64; 3]);

impl MeshCache {
    /// The mesh of `path` under `x ↦ R(scale·x) + translate`, loaded, checked closed
    /// and built into a [`SolidMesh`] on first use.
    pub fn get(
        &self,
        path: &Path,
        scale: f64,
        rotate_deg: [f64; 3],
        translate: [f64; 3],
    ) -> Result<Arc<SolidMesh>, MeshError> {
        let key = (
            path.to_path_buf(),
            scale.to_bits(),
            rotate_deg.map(f64::to_bits),
            translate.map(f64::to_bits),
        );
        let mut slot = self.0.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((k, m)) = slot.as_ref() {
            if *k == key {
                return Ok(m.clone());
            }
        }
        let mesh = load(path)?;
        mesh.check_closed()?;
        mesh.check_self_intersection()?;
        let solid = Arc::new(SolidMesh::new(
            mesh.transformed(scale, rotate_deg, translate),
        ));
        *slot = Some((key, solid.clone()));
        Ok(solid)
    }
}

impl Clone for MeshCache {
    fn clone(&self) -> Self {
        MeshCache(Mutex::new(
            self.0.lock().unwrap_or_else(|e| e.into_inner()).clone(),
        ))
    }
}

impl PartialEq for MeshCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

impl std::fmt::Debug for MeshCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("MeshCache")
    }
}

/// Triangles per leaf of the winding-number tree.
const LEAF: usize = 8;

#[derive(Clone, Debug, PartialEq)]
struct Node {
    lo: [f64; 3],
    hi: [f64; 3],
    /// Range of `SolidMesh::order` covered.
    start: u32,
    end: u32,
    /// Children, or `None` for a leaf.
    children: Option<(u32, u32)>,
    /// The node's boundary edges (directed), when fewer than its triangles.
    fan: Option<Vec<[u32; 2]>>,
}

/// A closed mesh ready for inside tests.
///
/// The winding number of a patch `P` of triangles depends only on its boundary: for
/// any surface `F` with `∂F = ∂P`, `P − F` is a closed cycle, whose winding number is
/// 0 at every point outside a convex set containing it. Each tree node keeps its
/// patch's boundary edges and, for points outside the node's box, sums the solid
/// angles of the fan joining the box centre to those edges — exactly the patch's
/// contribution (to round-off), with ~√n triangles instead of n.
#[derive(Clone, Debug, PartialEq)]
pub struct SolidMesh {
    pub mesh: TriMesh,
    order: Vec<u32>,
    nodes: Vec<Node>,
}

impl SolidMesh {
    /// Builds the tree (the mesh is assumed closed: see [`TriMesh::check_closed`]).
    pub fn new(mesh: TriMesh) -> SolidMesh {
        let centroids: Vec<[f64; 3]> = mesh
            .triangles
            .iter()
            .map(|t| {
                let [a, b, c] = mesh.corners(t);
                [0, 1, 2].map(|k| (a[k] + b[k] + c[k]) / 3.0)
            })
            .collect();
        let mut s = SolidMesh {
            order: (0..mesh.triangles.len() as u32).collect(),
            nodes: Vec::new(),
            mesh,
        };
        if !s.order.is_empty() {
            s.build(0, s.order.len(), &centroids);
        }
        s
    }

    /// Builds the node over `order[start..end]`, returns its index.
    fn build(&mut self, start: usize, end: usize, centroids: &[[f64; 3]]) -> u32 {
        let id = self.nodes.len() as u32;
        let (mut lo, mut hi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        let (mut clo, mut chi) = ([f64::INFINITY; 3], [f64::NEG_INFINITY; 3]);
        for &t in &self.order[start..end] {
            for p in self.mesh.corners(&self.mesh.triangles[t as usize]) {
                for a in 0..3 {
                    lo[a] = lo[a].min(p[a]);
                    hi[a] = hi[a].max(p[a]);
                }
            }
            let c = centroids[t as usize];
            for a in 0..3 {
                clo[a] = clo[a].min(c[a]);
                chi[a] = chi[a].max(c[a]);
            }
        }
        self.nodes.push(Node {
            lo,
            hi,
            start: start as u32,
            end: end as u32,
            children: None,
            fan: None,
        });
        let boundary = if end - start <= LEAF {
            let mut edges = Vec::with_capacity(3 * (end - start));
            for &t in &self.order[start..end] {
                let t = self.mesh.triangles[t as usize];
                edges.extend([[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]]);
            }
            chain_boundary(edges)
        } else {
            // Median split on the longest axis of the centroids' box.
            let axis = (0..3)
                .max_by(|&a, &b| (chi[a] - clo[a]).total_cmp(&(chi[b] - clo[b])))
                .unwrap_or(0);
            let mid = (start + end) / 2;
            self.order[start..end].select_nth_unstable_by(mid - start, |&x, &y| {
                centroids[x as usize][axis]
                    .total_cmp(&centroids[y as usize][axis])
                    .then(x.cmp(&y))
            });
            let l = self.build(start, mid, centroids);
            let r = self.build(mid, end, centroids);
            self.nodes[id as usize].children = Some((l, r));
            let mut edges = self.nodes[l as usize].fan.clone().unwrap_or_default();
            edges.extend(self.nodes[r as usize].fan.iter().flatten());
            // Children without a fan: their boundary is recomputed from triangles.
            for c in [l, r] {
                if self.nodes[c as usize].fan.is_none() {
                    edges.extend(self.triangle_edges(c));
                }
            }
            chain_boundary(edges)
        };
        // A fan is worth keeping only when it is smaller than the patch; without
        // one, the parent recomputes this node's boundary from its triangles.
        if boundary.len() < end - start {
            self.nodes[id as usize].fan = Some(boundary);
        }
        id
    }

    fn triangle_edges(&self, node: u32) -> Vec<[u32; 2]> {
        let n = &self.nodes[node as usize];
        let mut edges = Vec::new();
        for &t in &self.order[n.start as usize..n.end as usize] {
            let t = self.mesh.triangles[t as usize];
            edges.extend([[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]]);
        }
        edges
    }

    /// Generalised winding number `w(p) = Σ Ω_t(p) / 4π`: ±1 inside a closed mesh
    /// (sign by orientation), 0 outside, ±½ on the surface.
    pub fn winding_number(&self, p: [f64; 3]) -> f64 {
        if self.nodes.is_empty() {
            return 0.0;
        }
        self.node_angle(0, p) / (4.0 * PI)
    }

    /// Inside when `|w| > ½` (orientation-agnostic).
    pub fn contains(&self, p: [f64; 3]) -> bool {
        self.winding_number(p).abs() > 0.5
    }

    fn node_angle(&self, id: u32, p: [f64; 3]) -> f64 {
        let n = &self.nodes[id as usize];
        if let Some(fan) = &n.fan {
            // Strictly outside the box (with a relative margin for round-off), where
            // the fan equals the patch.
            let margin = 1e-9 * (1.0 + norm(sub(n.hi, n.lo)));
            let outside = (0..3).any(|a| p[a] < n.lo[a] - margin || p[a] > n.hi[a] + margin);
            if outside {
                let apex = [0, 1, 2].map(|a| 0.5 * (n.lo[a] + n.hi[a]));
                let v = &self.mesh.vertices;
                return fan
                    .iter()
                    .map(|e| solid_angle(p, apex, v[e[0] as usize], v[e[1] as usize]))
                    .sum();
            }
        }
        match n.children {
            Some((l, r)) => self.node_angle(l, p) + self.node_angle(r, p),
            None => self.order[n.start as usize..n.end as usize]
                .iter()
                .map(|&t| {
                    let [a, b, c] = self.mesh.corners(&self.mesh.triangles[t as usize]);
                    solid_angle(p, a, b, c)
                })
                .sum(),
        }
    }
}

/// Which lattice cells of side `h` lie wholly inside or outside a closed mesh, so
/// that only the samples of cells the surface passes through need a winding number.
///
/// A cell is a surface cell when some triangle overlaps its closed box (a conservative
/// separating-axis test). Face-adjacent non-surface cells have the same winding number
/// (a path between their centres stays in the two closed boxes, which no triangle
/// meets), so each 6-connected region of them gets the value at one cell centre.
#[derive(Clone, Debug)]
pub struct CellClasses {
    /// First cell of the grid (one layer of padding below the requested range).
    c0: [i64; 3],
    dims: [usize; 3],
    /// 0 outside, 1 inside, 2 surface.
    class: Vec<u8>,
}

const SURFACE: u8 = 2;
const UNSET: u8 = 3;

impl CellClasses {
    /// Whether cell `c` lies wholly inside (`Some(true)`), wholly outside
    /// (`Some(false)`), or is crossed by the surface or outside the grid (`None`).
    pub fn get(&self, c: [i64; 3]) -> Option<bool> {
        let mut idx = 0usize;
        for a in (0..3).rev() {
            let d = c[a] - self.c0[a];
            if d < 0 || d as usize >= self.dims[a] {
                return None;
            }
            idx = idx * self.dims[a] + d as usize;
        }
        match self.class[idx] {
            0 => Some(false),
            1 => Some(true),
            _ => None,
        }
    }

    /// Number of surface cells (for tests and reports).
    pub fn surface_cells(&self) -> usize {
        self.class.iter().filter(|&&c| c == SURFACE).count()
    }
}

/// Separating-axis test (Akenine-Möller 2001) of a triangle against the axis-aligned
/// cube `centre ± half`: `false` only when some axis separates them (box normals,
/// triangle normal, the nine edge × box-axis products). Degenerate axes never
/// separate, so the test errs towards "overlaps".
fn triangle_overlaps_cube(centre: [f64; 3], half: f64, tri: [[f64; 3]; 3]) -> bool {
    let v = tri.map(|p| sub(p, centre));
    let separated = |axis: [f64; 3]| {
        let p = v.map(|q| dot(axis, q));
        let r = half * (axis[0].abs() + axis[1].abs() + axis[2].abs());
        p.iter().fold(f64::INFINITY, |m, &x| m.min(x)) > r
            || p.iter().fold(f64::NEG_INFINITY, |m, &x| m.max(x)) < -r
    };
    let unit = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    if unit.iter().any(|&a| separated(a)) {
        return false;
    }
    let e = [sub(v[1], v[0]), sub(v[2], v[1]), sub(v[0], v[2])];
    if separated(cross(e[0], e[1])) {
        return false;
    }
    !e.iter()
        .any(|&ei| unit.iter().any(|&a| separated(cross(a, ei))))
}

impl SolidMesh {
    /// Classifies the cells `c0 ≤ (i, j, k) < c1` of the lattice of spacing `h`
    /// (cell `(i, j, k)` spans `[i h, (i+1) h] × …`).
    pub fn classify_cells(&self, c0: [i64; 3], c1: [i64; 3], h: f64) -> CellClasses {
        // One layer of padding, so that the region around the mesh is connected.
        let g0 = c0.map(|x| x - 1);
        let dims: [usize; 3] = [0, 1, 2].map(|a| (c1[a] - c0[a]).max(0) as usize + 2);
        let n = dims[0] * dims[1] * dims[2];
        let mut class = vec![UNSET; n];
        let index = |c: [usize; 3]| (c[2] * dims[1] + c[1]) * dims[0] + c[0];
        // Relative margin: sample points lie in their cell up to round-off.
        let half = 0.5 * h * (1.0 + 1e-6);
        for t in &self.mesh.triangles {
            let tri = self.mesh.corners(t);
            let mut lo = [0usize; 3];
            let mut hi = [0usize; 3];
            let mut empty = false;
            for a in 0..3 {
                let (mn, mx) = tri
                    .iter()
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, u), p| {
                        (l.min(p[a]), u.max(p[a]))
                    });
                let first = (((mn - half) / h).floor() as i64 - g0[a]).max(0);
                let last = (((mx + half) / h).floor() as i64 - g0[a]).min(dims[a] as i64 - 1);
                empty |= first > last;
                lo[a] = first as usize;
                hi[a] = last.max(0) as usize;
            }
            if empty {
                continue;
            }
            for k in lo[2]..=hi[2] {
                for j in lo[1]..=hi[1] {
                    for i in lo[0]..=hi[0] {
                        let idx = index([i, j, k]);
                        if class[idx] == SURFACE {
                            continue;
                        }
                        let c = [i, j, k];
                        let centre = [0, 1, 2].map(|a| ((c[a] as i64 + g0[a]) as f64 + 0.5) * h);
                        if triangle_overlaps_cube(centre, half, tri) {
                            class[idx] = SURFACE;
                        }
                    }
                }
            }
        }
        // Flood fill the remaining cells region by region (6-connected), each with the
        // winding number at its first cell's centre.
        let mut stack = Vec::new();
        for seed in 0..n {
            if class[seed] != UNSET {
                continue;
            }
            let c = [
                seed % dims[0],
                (seed / dims[0]) % dims[1],
                seed / (dims[0] * dims[1]),
            ];
            let p = [0, 1, 2].map(|a| ((c[a] as i64 + g0[a]) as f64 + 0.5) * h);
            let value = self.contains(p) as u8;
            class[seed] = value;
            stack.push(c);
            while let Some(c) = stack.pop() {
                for a in 0..3 {
                    for up in [false, true] {
                        let mut d = c;
                        if up {
                            if c[a] + 1 >= dims[a] {
                                continue;
                            }
                            d[a] += 1;
                        } else {
                            if c[a] == 0 {
                                continue;
                            }
                            d[a] -= 1;
                        }
                        let di = index(d);
                        if class[di] == UNSET {
                            class[di] = value;
                            stack.push(d);
                        }
                    }
                }
            }
        }
        CellClasses {
            c0: g0,
            dims,
            class,
        }
    }
}

/// The boundary of a 2-chain given by its triangles' directed edges: opposite edges
/// cancel, what remains (with multiplicity) is returned sorted, so that sums over it
/// are reproducible.
fn chain_boundary(edges: Vec<[u32; 2]>) -> Vec<[u32; 2]> {
    let mut net: HashMap<(u32, u32), i32> = HashMap::new();
    for [a, b] in edges {
        let (k, d) = edge_key(a, b);
        *net.entry(k).or_insert(0) += d;
    }
    let mut out = Vec::new();
    for ((a, b), n) in net {
        let e = if n > 0 { [a, b] } else { [b, a] };
        for _ in 0..n.unsigned_abs() {
            out.push(e);
        }
    }
    out.sort_unstable();
    out
}

/// A torus about the y axis (major radius `major`, minor `minor`), `nu × nv` quads
/// split into `2 nu nv` outward-oriented triangles.
pub fn torus(major: f64, minor: f64, nu: usize, nv: usize) -> TriMesh {
    let mut m = TriMesh::default();
    for i in 0..nu {
        let u = 2.0 * PI * i as f64 / nu as f64;
        for j in 0..nv {
            let v = 2.0 * PI * j as f64 / nv as f64;
            let rho = major + minor * v.cos();
            m.vertices
                .push([rho * u.cos(), minor * v.sin(), rho * u.sin()]);
        }
    }
    let id = |i: usize, j: usize| ((i % nu) * nv + j % nv) as u32;
    for i in 0..nu {
        for j in 0..nv {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            // (d − a) × (c − a) ≈ ∂P/∂v × ∂P/∂u points out of the tube.
            m.triangles.push([a, d, c]);
            m.triangles.push([a, c, b]);
        }
    }
    m
}

/// The closed surface swept by turning `profile` (points `[ρ, y]`, `ρ ≥ 0`, first and
/// last on the axis `ρ = 0`) about the y axis in `segments` steps; triangles face
/// outwards whichever way the profile runs.
pub fn revolve(profile: &[[f64; 2]], segments: usize) -> TriMesh {
    let mut m = TriMesh::default();
    let n = profile.len();
    let ring = |j: usize| 2 + (j - 1) * segments;
    // Poles first (indices 0 and 1), then one ring per interior profile point.
    m.vertices.push([0.0, profile[0][1], 0.0]);
    m.vertices.push([0.0, profile[n - 1][1], 0.0]);
    for p in &profile[1..n - 1] {
        for s in 0..segments {
            let u = 2.0 * PI * s as f64 / segments as f64;
            m.vertices.push([p[0] * u.cos(), p[1], p[0] * u.sin()]);
        }
    }
    let at = |j: usize, s: usize| (ring(j) + s % segments) as u32;
    for s in 0..segments {
        m.triangles.push([0, at(1, s), at(1, s + 1)]);
        for j in 1..n - 2 {
            m.triangles.push([at(j, s), at(j + 1, s), at(j + 1, s + 1)]);
            m.triangles.push([at(j, s), at(j + 1, s + 1), at(j, s + 1)]);
        }
        m.triangles.push([1, at(n - 2, s + 1), at(n - 2, s)]);
    }
    if m.signed_volume() < 0.0 {
        for t in &mut m.triangles {
            t.swap(1, 2);
        }
    }
    m
}

/// A hemispherical bowl opening upwards (+y): outer radius `outer`, wall `thickness`,
/// rim at y = 0, bottom at y = −outer; `segments` around, `steps` along each
/// quarter circle.
pub fn bowl(outer: f64, thickness: f64, segments: usize, steps: usize) -> TriMesh {
    let inner = outer - thickness;
    let arc = |r: f64, k: usize| {
        let a = -0.5 * PI + 0.5 * PI * k as f64 / steps as f64;
        [r * a.cos().max(0.0), r * a.sin()]
    };
    let mut profile: Vec<[f64; 2]> = (0..=steps).map(|k| arc(outer, k)).collect();
    profile.extend((0..=steps).rev().map(|k| arc(inner, k)));
    profile[0][0] = 0.0;
    let last = profile.len() - 1;
    profile[last][0] = 0.0;
    revolve(&profile, segments)
}

/// A yo-yo about the y axis: a ball of radius `ball` centred at the origin hanging from
/// a cord of radius `cord` (< `ball`) that leaves its top and ends `length` above the
/// ball's surface, as one closed solid of revolution; `segments` around, `steps` along
/// the ball's arc from the cord down to the bottom pole.
pub fn yoyo(ball: f64, cord: f64, length: f64, segments: usize, steps: usize) -> TriMesh {
    let join = (ball * ball - cord * cord).sqrt();
    let top = join + length;
    let start = join.atan2(cord);
    let mut profile = vec![[0.0, top], [cord, top]];
    // The cord in cells as long as it is wide, then the arc.
    let pieces = ((length / (2.0 * cord)).ceil() as usize).max(1);
    profile.extend((1..pieces).map(|k| [cord, top - length * k as f64 / pieces as f64]));
    profile.extend((0..=steps).map(|k| {
        let a = start - (start + 0.5 * PI) * k as f64 / steps as f64;
        [ball * a.cos(), ball * a.sin()]
    }));
    let last = profile.len() - 1;
    profile[last] = [0.0, -ball];
    revolve(&profile, segments)
}

/// An icosphere with `levels` subdivisions (20·4^levels outward triangles) whose
/// vertices are moved to radius `radius(direction)`. A radial graph over the sphere
/// cannot self-intersect, so any positive `radius` gives a valid closed mesh.
pub fn radial_icosphere(levels: usize, radius: impl Fn([f64; 3]) -> f64) -> TriMesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v: Vec<[f64; 3]> = vec![
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let unit = |p: [f64; 3]| {
        let l = norm(p);
        p.map(|x| x / l)
    };
    v = v.into_iter().map(unit).collect();
    let mut f: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..levels {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(4 * f.len());
        for tri in &f {
            let mut m = [0u32; 3];
            for c in 0..3 {
                let (k, _) = edge_key(tri[c], tri[(c + 1) % 3]);
                m[c] = *mid.entry(k).or_insert_with(|| {
                    let (a, b) = (v[k.0 as usize], v[k.1 as usize]);
                    v.push(unit([a[0] + b[0], a[1] + b[1], a[2] + b[2]]));
                    (v.len() - 1) as u32
                });
            }
            next.push([tri[0], m[0], m[2]]);
            next.push([tri[1], m[1], m[0]]);
            next.push([tri[2], m[2], m[1]]);
            next.push(m);
        }
        f = next;
    }
    let vertices = v
        .into_iter()
        .map(|d| {
            let r = radius(d);
            d.map(|x| r * x)
        })
        .collect();
    TriMesh {
        vertices,
        triangles: f,
    }
}

/// The shipped "bunny-like" blob: an egg-shaped body (unit size, +y up, facing +z)
/// with a head bump and two long ear bumps, on a 3-times subdivided icosphere
/// (1280 triangles).
pub fn bunny_blob() -> TriMesh {
    let bump = |d: [f64; 3], centre: [f64; 3], width: f64| {
        let c = {
            let l = norm(centre);
            centre.map(|x| x / l)
        };
        let angle = dot(d, c).clamp(-1.0, 1.0).acos();
        (-(angle / width).powi(2)).exp()
    };
    radial_icosphere(3, |d| {
        // Ellipsoid radius along d: semi-axes 0.8 (x), 0.7 (y), 1.0 (z).
        let body = 1.0 / ((d[0] / 0.8).powi(2) + (d[1] / 0.7).powi(2) + d[2].powi(2)).sqrt();
        body + 0.35 * bump(d, [0.0, 0.8, 1.0], 0.45)
            + 0.8 * bump(d, [0.3, 1.0, 0.15], 0.22)
            + 0.8 * bump(d, [-0.3, 1.0, 0.15], 0.22)
            + 0.15 * bump(d, [0.0, 0.2, -1.0], 0.3)
    })
}
