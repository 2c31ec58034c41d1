//! Mesh readers for the render binary: OBJ (tobj, without its MTL reader), OFF and PLY (ASCII and binary,
//! careful hand-written parsers).
//!
//! Polygons are fan-triangulated. PLY per-face `red/green/blue` properties become face colours; otherwise faces get
//! the default colour. Every failure is a [`MeshError`]; no input makes these readers panic, hang or read
//! without bound: only regular files are opened (not FIFOs or devices), at most [`MAX_FILE_BYTES`] are read, and
//! declared counts are checked against the file's content.

use std::fs;
use std::io::{BufReader, Read};
use std::path::{Path, PathBuf};

use thiserror::Error;

/// Largest mesh file the binary reads, in bytes (1 GiB, the Python loader's limit too).
pub const MAX_FILE_BYTES: u64 = meshadv_raster::MAX_MESH_FILE_BYTES;

/// Errors of the mesh readers, each naming the file (when there is one) and what is wrong.
#[derive(Debug, Clone, PartialEq, Error)]
pub enum MeshError {
    /// The path does not exist.
    #[error("{path}: no such file")]
    NotFound {
        /// The path given.
        path: PathBuf,
    },
    /// The path is a directory, FIFO, device or socket (reading it could block or never end).
    #[error("{path}: not a regular file ({kind}); give a mesh file")]
    NotRegularFile {
        /// The path given.
        path: PathBuf,
        /// What it is instead.
        kind: &'static str,
    },
    /// The file is larger than [`MAX_FILE_BYTES`].
    #[error("{path}: the file is larger than the {limit}-byte limit")]
    TooLarge {
        /// The path given.
        path: PathBuf,
        /// The limit.
        limit: u64,
    },
    /// Reading failed.
    #[error("{path}: cannot read: {message}")]
    Io {
        /// The path given.
        path: PathBuf,
        /// The operating system's message.
        message: String,
    },
    /// The extension is not one of `.obj`, `.off`, `.ply`.
    #[error("{path}: unsupported mesh format {ext:?} (expected .obj, .off or .ply)")]
    UnsupportedFormat {
        /// The path given.
        path: PathBuf,
        /// Its extension.
        ext: String,
    },
    /// The content does not follow the format.
    #[error("malformed {format}: {message}")]
    Malformed {
        /// `OBJ`, `OFF` or `PLY`.
        format: &'static str,
        /// What is wrong, with the line, element or face.
        message: String,
    },
    /// The mesh parsed but cannot be rendered (empty, non-finite, bad index).
    #[error("{message}")]
    InvalidMesh {
        /// What is wrong.
        message: String,
    },
    /// Another error, with the file it concerns.
    #[error("{path}: {source}")]
    InFile {
        /// The path given.
        path: PathBuf,
        /// The error.
        source: Box<MeshError>,
    },
}

impl MeshError {
    fn malformed(format: &'static str, message: String) -> Self {
        let prefix = format!("malformed {format}: ");
        let message = message
            .strip_prefix(&prefix)
            .map(str::to_string)
            .unwrap_or(message);
        MeshError::Malformed { format, message }
    }
}

/// A triangle mesh with per-face colours, flat arrays.
#[derive(Debug, Clone, PartialEq)]
pub struct Mesh {
    /// `(N, 3)` positions.
    pub vertices: Vec<f32>,
    /// `(M, 3)` vertex indices.
    pub faces: Vec<i32>,
    /// `(M, 3)` RGB in `[0, 1]`, or `None` when the file has none.
    pub face_colors: Option<Vec<f32>>,
}

/// Reads a whole regular file of at most `limit` bytes.
///
/// FIFOs, devices, directories and sockets are refused before opening (a FIFO would block, `/dev/zero` never
/// ends); symbolic links are followed and judged by their target.
pub fn read_regular_file(path: &Path, limit: u64) -> Result<Vec<u8>, MeshError> {
    let meta = match fs::metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            return Err(MeshError::NotFound {
                path: path.to_path_buf(),
            })
        }
        Err(e) => {
            return Err(MeshError::Io {
                path: path.to_path_buf(),
                message: e.to_string(),
            })
        }
    };
    if !meta.is_file() {
        return Err(MeshError::NotRegularFile {
            path: path.to_path_buf(),
            kind: file_kind(&meta),
        });
    }
    let io = |e: std::io::Error| MeshError::Io {
        path: path.to_path_buf(),
        message: e.to_string(),
    };
    let file = fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    if !meta.is_file() {
        return Err(MeshError::NotRegularFile {
            path: path.to_path_buf(),
            kind: file_kind(&meta),
        });
    }
    if meta.len() > limit {
        return Err(MeshError::TooLarge {
            path: path.to_path_buf(),
            limit,
        });
    }
    let mut bytes = Vec::new();
    file.take(limit + 1).read_to_end(&mut bytes).map_err(io)?;
    if bytes.len() as u64 > limit {
        return Err(MeshError::TooLarge {
            path: path.to_path_buf(),
            limit,
        });
    }
    Ok(bytes)
}

fn file_kind(meta: &fs::Metadata) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    let t = meta.file_type();
    if t.is_dir() {
        "a directory"
    } else if t.is_fifo() {
        "a FIFO"
    } else if t.is_char_device() {
        "a character device"
    } else if t.is_block_device() {
        "a block device"
    } else if t.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

/// Reads a mesh, choosing the parser from the extension (`.obj`, `.off`, `.ply`, case-insensitive).
pub fn load_mesh(path: &Path) -> Result<Mesh, MeshError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    if !matches!(ext.as_str(), "obj" | "off" | "ply") {
        return Err(MeshError::UnsupportedFormat {
            path: path.to_path_buf(),
            ext,
        });
    }
    let bytes = read_regular_file(path, MAX_FILE_BYTES)?;
    let in_file = |e: MeshError| MeshError::InFile {
        path: path.to_path_buf(),
        source: Box::new(e),
    };
    let mesh = match ext.as_str() {
        "obj" => parse_obj(&bytes),
        "off" => parse_off(&bytes),
        _ => parse_ply(&bytes),
    }
    .map_err(in_file)?;
    check_mesh(&mesh).map_err(in_file)?;
    Ok(mesh)
}

/// Checks that the mesh is non-empty, finite, that faces refer to existing vertices and that some face has an
/// area (the rule of the Python loader: a face is degenerate when two corners are the same vertex or the cross
/// product of its edges, in f64, is exactly zero).
pub fn check_mesh(mesh: &Mesh) -> Result<(), MeshError> {
    let bad = |message: String| MeshError::InvalidMesh { message };
    let n = mesh.vertices.len() / 3;
    if n == 0 || mesh.faces.is_empty() {
        return Err(bad("the mesh has no vertices or no faces".into()));
    }
    if let Some(i) = mesh.vertices.iter().position(|v| !v.is_finite()) {
        return Err(bad(format!("vertex {} has a non-finite coordinate", i / 3)));
    }
    if let Some(i) = mesh.faces.iter().position(|&f| f < 0 || f as usize >= n) {
        return Err(bad(format!(
            "face {} refers to vertex {}, but there are {n} vertices",
            i / 3,
            mesh.faces[i]
        )));
    }
    let corner = |i: i32| {
        let o = i as usize * 3;
        [0, 1, 2].map(|a| mesh.vertices[o + a] as f64)
    };
    let has_area = |t: &[i32]| {
        let [a, b, c] = [corner(t[0]), corner(t[1]), corner(t[2])];
        let (u, v) = (
            [0, 1, 2].map(|k| b[k] - a[k]),
            [0, 1, 2].map(|k| c[k] - a[k]),
        );
        let cross = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        t[0] != t[1] && t[1] != t[2] && t[0] != t[2] && cross.iter().any(|&x| x != 0.0)
    };
    if !mesh.faces.chunks_exact(3).any(has_area) {
        return Err(bad(
            "every face is degenerate (repeated corner or zero area)".into(),
        ));
    }
    Ok(())
}

/// Parses OBJ text with tobj. Material libraries are not read (the binary does not use them, and tobj's MTL
/// reader panics on some malformed lines such as `Kd 0 0`); OBJ indices must be 1-based, so `f 0 1 2` is refused.
pub fn parse_obj(bytes: &[u8]) -> Result<Mesh, MeshError> {
    obj_precheck(bytes).map_err(|m| MeshError::malformed("OBJ", m))?;
    let opts = tobj::LoadOptions {
        triangulate: true,
        single_index: true,
        ..Default::default()
    };
    let mut reader = BufReader::new(bytes);
    let (models, _materials) =
        tobj::load_obj_buf(&mut reader, &opts, |_| Err(tobj::LoadError::GenericFailure))
            .map_err(|e| MeshError::malformed("OBJ", e.to_string()))?;
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for m in models {
        let offset = (vertices.len() / 3) as i64;
        vertices.extend_from_slice(&m.mesh.positions);
        for &i in &m.mesh.indices {
            let v = offset + i as i64;
            faces.push(
                i32::try_from(v)
                    .map_err(|_| MeshError::malformed("OBJ", "too many vertices".into()))?,
            );
        }
    }
    Ok(Mesh {
        vertices,
        faces,
        face_colors: None,
    })
}

/// Line checks tobj does not make: `v` needs 3 numbers, face indices are non-zero and within the vertices.
fn obj_precheck(bytes: &[u8]) -> Result<(), String> {
    let text = String::from_utf8_lossy(bytes);
    let mut vertices: i64 = 0;
    let mut faces: Vec<(usize, i64)> = Vec::new();
    for (lineno, raw) in text.lines().enumerate() {
        let line = raw.split('#').next().unwrap_or("");
        let mut tokens = line.split_whitespace();
        match tokens.next() {
            Some("v") => {
                let nums: Vec<&str> = tokens.collect();
                if nums.len() < 3 || nums.iter().any(|t| t.parse::<f64>().is_err()) {
                    return Err(format!(
                        "line {}: a vertex needs 3 numbers, got {:?}",
                        lineno + 1,
                        raw.trim()
                    ));
                }
                vertices += 1;
            }
            Some("f") | Some("l") | Some("p") => {
                for corner in tokens {
                    let head = corner.split('/').next().unwrap_or("");
                    let i: i64 = head
                        .parse()
                        .map_err(|_| format!("line {}: bad vertex index {corner:?}", lineno + 1))?;
                    if i == 0 {
                        return Err(format!(
                            "line {}: OBJ vertex indices start at 1, got 0",
                            lineno + 1
                        ));
                    }
                    if i < 0 && i.checked_neg().is_none_or(|n| n > vertices) {
                        return Err(format!(
                            "line {}: relative index {i} refers before the first vertex",
                            lineno + 1
                        ));
                    }
                    faces.push((lineno + 1, i));
                }
            }
            _ => {}
        }
    }
    if let Some((lineno, i)) = faces.iter().find(|(_, i)| *i > vertices) {
        return Err(format!(
            "line {lineno}: vertex index {i} is out of range (the file has {vertices} vertices)"
        ));
    }
    Ok(())
}

fn fan(poly: &[i64], faces: &mut Vec<i32>, what: &str) -> Result<(), String> {
    if poly.len() < 3 {
        return Err(format!(
            "{what}: a face needs at least 3 vertices, got {}",
            poly.len()
        ));
    }
    for k in 1..poly.len() - 1 {
        for &v in &[poly[0], poly[k], poly[k + 1]] {
            faces.push(
                i32::try_from(v).map_err(|_| format!("{what}: vertex index {v} out of range"))?,
            );
        }
    }
    Ok(())
}

/// Parses an ASCII OFF file: `OFF` header (counts on the same or the next line), one vertex per line (extra values
/// such as colours ignored), one face per line `k i1 .. ik` (trailing colours ignored); `#` comments. The file
/// must hold exactly the declared number of vertex and face lines.
pub fn parse_off(bytes: &[u8]) -> Result<Mesh, MeshError> {
    off_body(bytes).map_err(|m| MeshError::malformed("OFF", m))
}

fn off_body(bytes: &[u8]) -> Result<Mesh, String> {
    let text =
        std::str::from_utf8(bytes).map_err(|_| "malformed OFF: not UTF-8 text".to_string())?;
    let mut lines = text
        .lines()
        .map(|l| l.split('#').next().unwrap_or("").trim())
        .filter(|l| !l.is_empty());
    let first = lines.next().ok_or("malformed OFF: empty file")?;
    let mut head: Vec<&str> = first.split_whitespace().collect();
    if head[0] != "OFF" {
        return Err(format!(
            "malformed OFF: expected the OFF header, got {:?}",
            head[0]
        ));
    }
    head.remove(0);
    if head.is_empty() {
        head = lines
            .next()
            .ok_or("malformed OFF: missing the counts line")?
            .split_whitespace()
            .collect();
    }
    let count = |i: usize, what: &str| -> Result<usize, String> {
        let s = head
            .get(i)
            .ok_or_else(|| format!("malformed OFF: missing the {what}"))?;
        s.parse::<usize>()
            .map_err(|_| format!("malformed OFF: bad {what} {s:?}"))
    };
    let (nv, nf) = (count(0, "vertex count")?, count(1, "face count")?);
    if nv > 100_000_000 || nf > 100_000_000 {
        return Err(format!(
            "malformed OFF: absurd counts ({nv} vertices, {nf} faces)"
        ));
    }
    let mut vertices = Vec::with_capacity(nv * 3);
    for i in 0..nv {
        let l = lines
            .next()
            .ok_or_else(|| format!("malformed OFF: expected {nv} vertices, file ends at {i}"))?;
        let xyz: Vec<&str> = l.split_whitespace().take(3).collect();
        if xyz.len() < 3 {
            return Err(format!(
                "malformed OFF: vertex {i}: expected 3 coordinates in {l:?}"
            ));
        }
        for s in xyz {
            vertices.push(
                s.parse::<f32>()
                    .map_err(|_| format!("malformed OFF: vertex {i}: bad number {s:?}"))?,
            );
        }
    }
    let mut faces = Vec::with_capacity(nf * 3);
    for fi in 0..nf {
        let l = lines
            .next()
            .ok_or_else(|| format!("malformed OFF: expected {nf} faces, file ends at {fi}"))?;
        let nums: Vec<&str> = l.split_whitespace().collect();
        let k: usize = nums[0]
            .parse()
            .map_err(|_| format!("malformed OFF: face {fi}: bad vertex count {:?}", nums[0]))?;
        if k >= nums.len() {
            return Err(format!(
                "malformed OFF: face {fi}: expected {k} indices in {l:?}"
            ));
        }
        let poly: Result<Vec<i64>, String> = nums[1..=k]
            .iter()
            .map(|s| {
                s.parse::<i64>()
                    .map_err(|_| format!("malformed OFF: face {fi}: bad index {s:?}"))
            })
            .collect();
        fan(&poly?, &mut faces, &format!("malformed OFF: face {fi}"))?;
    }
    if let Some(extra) = lines.next() {
        return Err(format!(
            "malformed OFF: the header declares {nv} vertices and {nf} faces, but more lines follow: {extra:?}"
        ));
    }
    Ok(Mesh {
        vertices,
        faces,
        face_colors: None,
    })
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    fn parse(s: &str) -> Result<Scalar, String> {
        Ok(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return Err(format!("malformed PLY: unknown property type {s:?}")),
        })
    }

    fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }
}

#[derive(Debug, Clone)]
struct Property {
    name: String,
    kind: Scalar,
    /// Count type for list properties.
    list: Option<Scalar>,
}

#[derive(Debug, Clone)]
struct Element {
    name: String,
    count: usize,
    props: Vec<Property>,
}

#[derive(Clone, Copy, PartialEq)]
enum Format {
    Ascii,
    Le,
    Be,
}

/// Sequential value reader over the PLY body.
struct Reader<'a> {
    bytes: &'a [u8],
    pos: usize,
    format: Format,
    tokens: std::str::SplitAsciiWhitespace<'a>,
}

impl Reader<'_> {
    fn read(&mut self, kind: Scalar) -> Result<f64, String> {
        if self.format == Format::Ascii {
            let t = self
                .tokens
                .next()
                .ok_or("malformed PLY: unexpected end of data")?;
            return t
                .parse::<f64>()
                .map_err(|_| format!("malformed PLY: bad number {t:?}"));
        }
        let n = kind.size();
        let b = self
            .bytes
            .get(self.pos..self.pos + n)
            .ok_or("malformed PLY: file is truncated")?;
        self.pos += n;
        let mut a = [0u8; 8];
        a[..n].copy_from_slice(b);
        if self.format == Format::Be {
            a[..n].reverse();
        }
        Ok(match kind {
            Scalar::I8 => a[0] as i8 as f64,
            Scalar::U8 => a[0] as f64,
            Scalar::I16 => i16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::U16 => u16::from_le_bytes([a[0], a[1]]) as f64,
            Scalar::I32 => i32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::U32 => u32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F32 => f32::from_le_bytes([a[0], a[1], a[2], a[3]]) as f64,
            Scalar::F64 => f64::from_le_bytes(a),
        })
    }
}

/// Parses a PLY file (ASCII, binary little or big endian): `vertex` x/y/z, `face` `vertex_indices` (or
/// `vertex_index`) lists, optional face `red/green/blue` (uchar 0-255 or float 0-1). The body must hold exactly
/// the values the header declares.
pub fn parse_ply(bytes: &[u8]) -> Result<Mesh, MeshError> {
    ply_body(bytes).map_err(|m| MeshError::malformed("PLY", m))
}

fn ply_body(bytes: &[u8]) -> Result<Mesh, String> {
    const END: &[u8] = b"end_header";
    let end = bytes
        .windows(END.len())
        .position(|w| w == END)
        .ok_or("malformed PLY: no end_header")?;
    let mut body_start = end + END.len();
    // Skip the rest of the end_header line (\n or \r\n).
    while body_start < bytes.len() && bytes[body_start] != b'\n' {
        body_start += 1;
    }
    body_start += 1;
    let header =
        std::str::from_utf8(&bytes[..end]).map_err(|_| "malformed PLY: header is not text")?;
    let mut lines = header.lines();
    if lines.next().map(str::trim) != Some("ply") {
        return Err("malformed PLY: missing the 'ply' magic line".into());
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let w: Vec<&str> = line.split_whitespace().collect();
        match w.first().copied() {
            Some("format") => {
                format = Some(match w.get(1).copied() {
                    Some("ascii") => Format::Ascii,
                    Some("binary_little_endian") => Format::Le,
                    Some("binary_big_endian") => Format::Be,
                    other => return Err(format!("malformed PLY: unknown format {other:?}")),
                })
            }
            Some("element") => {
                let (Some(name), Some(count)) = (w.get(1), w.get(2)) else {
                    return Err(format!("malformed PLY: bad element line {line:?}"));
                };
                let count: usize = count
                    .parse()
                    .map_err(|_| format!("malformed PLY: bad element count {count:?}"))?;
                if count > 200_000_000 {
                    return Err(format!("malformed PLY: absurd element count {count}"));
                }
                elements.push(Element {
                    name: name.to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            Some("property") => {
                let el = elements
                    .last_mut()
                    .ok_or("malformed PLY: property before any element")?;
                let prop = if w.get(1) == Some(&"list") {
                    let (Some(ct), Some(it), Some(name)) = (w.get(2), w.get(3), w.get(4)) else {
                        return Err(format!("malformed PLY: bad list property {line:?}"));
                    };
                    Property {
                        name: name.to_string(),
                        kind: Scalar::parse(it)?,
                        list: Some(Scalar::parse(ct)?),
                    }
                } else {
                    let (Some(t), Some(name)) = (w.get(1), w.get(2)) else {
                        return Err(format!("malformed PLY: bad property {line:?}"));
                    };
                    Property {
                        name: name.to_string(),
                        kind: Scalar::parse(t)?,
                        list: None,
                    }
                };
                el.props.push(prop);
            }
            _ => {}
        }
    }
    let format = format.ok_or("malformed PLY: no format line")?;
    let body = bytes.get(body_start..).unwrap_or(&[]);
    let text = if format == Format::Ascii {
        std::str::from_utf8(body).map_err(|_| "malformed PLY: ASCII body is not text")?
    } else {
        ""
    };
    let mut rd = Reader {
        bytes: body,
        pos: 0,
        format,
        tokens: text.split_ascii_whitespace(),
    };
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    let mut colors: Vec<f32> = Vec::new();
    let mut have_vertex = false;
    for el in &elements {
        let is_vertex = el.name == "vertex";
        let is_face = el.name == "face";
        let pos_idx: Vec<Option<usize>> = ["x", "y", "z"]
            .iter()
            .map(|n| {
                el.props
                    .iter()
                    .position(|p| p.name == *n && p.list.is_none())
            })
            .collect();
        if is_vertex {
            have_vertex = true;
            if pos_idx.iter().any(Option::is_none) {
                return Err("malformed PLY: vertex element lacks x, y or z".into());
            }
        }
        let color_idx: Vec<Option<usize>> = ["red", "green", "blue"]
            .iter()
            .map(|n| {
                el.props
                    .iter()
                    .position(|p| p.name == *n && p.list.is_none())
            })
            .collect();
        let face_colors = is_face && color_idx.iter().all(Option::is_some);
        for row in 0..el.count {
            let mut xyz = [0f32; 3];
            let mut rgb = [0f32; 3];
            for (pi, p) in el.props.iter().enumerate() {
                if let Some(ct) = p.list {
                    let k = rd.read(ct)?;
                    if !(0.0..=1_000_000.0).contains(&k) || k.fract() != 0.0 {
                        return Err(format!(
                            "malformed PLY: {} {row}: bad list length {k}",
                            el.name
                        ));
                    }
                    let mut items = Vec::with_capacity(k as usize);
                    for _ in 0..k as usize {
                        let x = rd.read(p.kind)?;
                        // A float list (indices as doubles) must hold integers: NaN or 1.5 is no index.
                        if x.fract() != 0.0 || x.abs() > i64::MAX as f64 {
                            return Err(format!(
                                "malformed PLY: {} {row}: list {} holds {x}, not an integer",
                                el.name, p.name
                            ));
                        }
                        items.push(x as i64);
                    }
                    if is_face && (p.name == "vertex_indices" || p.name == "vertex_index") {
                        fan(&items, &mut faces, &format!("malformed PLY: face {row}"))?;
                    }
                } else {
                    let v = rd.read(p.kind)?;
                    if is_vertex {
                        for a in 0..3 {
                            if pos_idx[a] == Some(pi) {
                                xyz[a] = v as f32;
                            }
                        }
                    }
                    if face_colors {
                        for a in 0..3 {
                            if color_idx[a] == Some(pi) {
                                rgb[a] = if matches!(p.kind, Scalar::F32 | Scalar::F64) {
                                    v as f32
                                } else {
                                    v as f32 / 255.0
                                };
                            }
                        }
                    }
                }
            }
            if is_vertex {
                vertices.extend_from_slice(&xyz);
            }
            if face_colors {
                // One colour per triangle of the fan.
                let tris = faces.len() / 3 - colors.len() / 3;
                for _ in 0..tris {
                    colors.extend_from_slice(&rgb);
                }
            }
        }
    }
    if !have_vertex {
        return Err("malformed PLY: no vertex element".into());
    }
    if format == Format::Ascii {
        if let Some(extra) = rd.tokens.next() {
            return Err(format!(
                "malformed PLY: the body holds more values than the header declares (next: {extra:?})"
            ));
        }
    } else if rd.pos != body.len() {
        return Err(format!(
            "malformed PLY: {} bytes after the last declared element (wrong counts in the header?)",
            body.len() - rd.pos
        ));
    }
    let face_colors = (!colors.is_empty() && colors.len() == faces.len()).then_some(colors);
    Ok(Mesh {
        vertices,
        faces,
        face_colors,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn off_quads_are_fan_triangulated_and_counts_may_share_the_header_line() {
        let m = parse_off(b"OFF 4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3 255 0 0\n")
            .expect("valid");
        assert_eq!(m.vertices.len(), 12);
        assert_eq!(m.faces, vec![0, 1, 2, 0, 2, 3]);
    }

    #[test]
    fn off_errors_say_what_is_wrong() {
        assert!(parse_off(b"OFF\n3 1 0\n0 0 0\n1 0 x\n0 1 0\n3 0 1 2\n")
            .expect_err("bad")
            .to_string()
            .contains("vertex 1"));
        assert!(parse_off(b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n")
            .expect_err("bad")
            .to_string()
            .contains("expected 1 faces"));
        assert!(parse_off(b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2 0 1\n")
            .expect_err("bad")
            .to_string()
            .contains("at least 3"));
    }

    fn binary_ply(big_endian: bool) -> Vec<u8> {
        let fmt = if big_endian {
            "binary_big_endian"
        } else {
            "binary_little_endian"
        };
        let mut b = format!(
            "ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty double z\n\
             element face 1\nproperty list uchar uint vertex_indices\nend_header\n"
        )
        .into_bytes();
        for (x, y, z) in [(0f32, 0f32, 0.5f64), (1.0, 0.0, 0.5), (0.0, 1.0, 0.5)] {
            if big_endian {
                b.extend(x.to_be_bytes());
                b.extend(y.to_be_bytes());
                b.extend(z.to_be_bytes());
            } else {
                b.extend(x.to_le_bytes());
                b.extend(y.to_le_bytes());
                b.extend(z.to_le_bytes());
            }
        }
        b.push(3);
        for i in [2u32, 1, 0] {
            b.extend(if big_endian {
                i.to_be_bytes()
            } else {
                i.to_le_bytes()
            });
        }
        b
    }

    #[test]
    fn binary_ply_both_endiannesses() {
        for be in [false, true] {
            let m = parse_ply(&binary_ply(be)).expect("valid");
            assert_eq!(
                m.vertices,
                vec![0.0, 0.0, 0.5, 1.0, 0.0, 0.5, 0.0, 1.0, 0.5]
            );
            assert_eq!(m.faces, vec![2, 1, 0]);
        }
        let mut cut = binary_ply(false);
        cut.truncate(cut.len() - 2);
        assert!(parse_ply(&cut)
            .expect_err("truncated")
            .to_string()
            .contains("truncated"));
    }

    #[test]
    fn ascii_ply_face_colours() {
        let text = "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\nproperty float z\n\
                    element face 1\nproperty list uchar int vertex_indices\nproperty uchar red\nproperty uchar green\n\
                    property uchar blue\nend_header\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3 255 0 51\n";
        let m = parse_ply(text.as_bytes()).expect("valid");
        assert_eq!(m.faces.len(), 6);
        assert_eq!(m.face_colors, Some(vec![1.0, 0.0, 0.2, 1.0, 0.0, 0.2]));
    }
}
